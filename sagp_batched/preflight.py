"""Checks of everything a run names (display, Ray, run directory, model, Ray cluster) before any trial runs.

Each check raises ``PreflightError`` with a one-line message and leaves nothing behind: a study that
would fail on its first trial, or after an hour of them, fails here in seconds instead.
"""
from __future__ import annotations

import contextlib
import os
import socket
import sys
from pathlib import Path

from .config import Config, ConfigError, PlannerConfig, RatingConfig
from .planning.device import planning_device
from .rating.zone_rating import RatingError, VLMRequestError
from .rating.vlm import OpenAIVLM, TransformersVLM
from .robot.description import robot_of

# A reachable cluster accepts a TCP connection in milliseconds; seconds only make a dead one slow to report.
RAY_CONNECT_TIMEOUT_S = 3.0
# Ray addresses that name no host to connect to ("auto" finds a local cluster, "local" starts one).
RAY_ADDRESS_KEYWORDS = ("auto", "local")


class PreflightError(ValueError):
    """A setting that would make the run fail; the message is one line."""

    def __init__(self, message: str):
        super().__init__(" ".join(message.split()))


def check_display(gui: bool) -> None:
    """A GUI run on Linux has a display to open: without one PyBullet's GUI connection waits forever."""
    if gui and sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise PreflightError("--gui needs a display, and neither $DISPLAY nor $WAYLAND_DISPLAY is set (drop --gui to run headless)")


def check_ray_installed() -> None:
    """Ray imports: the study imports it only after writing the run directory's config and provenance."""
    try:
        import ray  # noqa: F401
    except ImportError as exc:
        raise PreflightError(f"--backend ray needs Ray, which does not import ({exc}): pip install 'sagp-batched[ray]'") from exc


def check_out_dir(out: str | Path) -> None:
    """Create the run directory and write and remove a probe file in it; directories created here are removed again."""
    out_dir = Path(out).expanduser()
    created: list[Path] = []  # deepest first, the order to remove them in
    for directory in (out_dir, *out_dir.parents):
        if directory.exists():
            break
        created.append(directory)
    probe = out_dir / f".preflight-{os.getpid()}"
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise PreflightError(f"cannot write the run directory {out_dir}: {exc.strerror or exc}") from exc
    finally:
        for directory in created:
            with contextlib.suppress(OSError):
                directory.rmdir()


def check_rater(rating: RatingConfig) -> None:
    """The model of a model backend can be used: its config loads (transformers) or the endpoint serves it (openai)."""
    try:
        if rating.backend == "transformers":
            TransformersVLM.check_loadable(rating)
        elif rating.backend == "openai":
            served = OpenAIVLM(rating).served_models()
            if rating.model not in served:
                raise PreflightError(
                    f"model '{rating.model}' is not served at {rating.endpoint.rstrip('/')}/models "
                    f"(served: {', '.join(served) or 'none'})"
                )
    except (RatingError, VLMRequestError) as exc:
        raise PreflightError(f"rater '{rating.backend}': {exc}") from exc


def check_planner_device(planner: PlannerConfig) -> None:
    """The planner's device exists on this machine and this torch can use it."""
    try:
        planning_device(planner)
    except ValueError as exc:
        raise PreflightError(str(exc)) from exc


def check_ray_address(address: str, flag: str = "--address") -> None:
    """A TCP connection to ``ray://host:port`` (or ``host:port``) opens; Ray itself is not started.
    ``flag`` is the option the message names as the address's source."""
    if address in RAY_ADDRESS_KEYWORDS:
        return
    host, _, port = address.removeprefix("ray://").rpartition(":")
    host = host.strip("[]")  # an IPv6 host is written [::1]:10001
    if not host or not port.isdigit():
        raise PreflightError(f"{flag} {address}: expected ray://host:port or host:port")
    try:
        with socket.create_connection((host, int(port)), timeout=RAY_CONNECT_TIMEOUT_S):
            pass
    except OSError as exc:
        raise PreflightError(f"{flag} {address}: cannot reach the Ray cluster: {exc.strerror or exc}") from exc


def check_gripper(config: Config, with_arm: bool) -> None:
    """The gripper takes the configured grip force, and a run ``with_arm`` has it on the robot's arm."""
    try:
        robot = robot_of(config)
        if with_arm:
            robot.require_mounted_gripper("a run with the arm")
    except ConfigError as exc:
        raise PreflightError(str(exc)) from None


def preflight(config: Config, with_arm: bool = True) -> None:
    """Every check the resolved ``config`` calls for: only backends the run uses are checked; ``with_arm``: the run
    executes grasps with the robot's arm (the study, an arm-mode dataset)."""
    check_display(config.run.gui)
    check_gripper(config, with_arm)
    if config.run.backend == "ray":
        check_ray_installed()
    check_out_dir(config.run.out)
    check_planner_device(config.planner)
    if config.run.backend == "ray" and config.run.ray_address:
        check_ray_address(config.run.ray_address)
    check_rater(config.rating)

"""A run directory: one run's settings, the lock that keeps it to one process, and its files written whole.

Guarantees: a directory holds the outputs of one run's settings and object set only (``check_same_run``); one
process writes it at a time; a file is replaced whole or not at all. A study's trials file is ``study.trials_file``.

- ``RunLock`` holds an exclusive lock on ``.lock`` for the whole run; a second process is refused.
"""
from __future__ import annotations

import dataclasses
import errno
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .config import Config, ConfigError

# One line per unit a worker process finished: its pid, node, units run so far, resident memory.
WORKERS_FILE = "workers.jsonl"
LOCK_FILE = ".lock"
CONFIG_FILE = "config.json"
PROVENANCE_FILE = "provenance.json"
# Settings that say how a run is executed or which of its trials to run, not what a record holds:
# they may differ on resume.
EXECUTION_ONLY = {"out", "workers", "backend", "ray_address", "gui", "trial_timeout_s", "objects", "tasks", "methods",
                  "n_trials", "save_frames", "export_grasps", "keep_errors"}


class RunDirectoryError(ConfigError):
    """The run directory cannot take this run; the message is one line."""


class RunDirectoryMismatch(RunDirectoryError):
    """The run directory holds a run made with other settings or another object set."""


class RunDirectoryBusy(RunDirectoryError):
    """Another process is running into the same directory."""


def os_reason(exc: OSError) -> str:
    """The system's one-line reason for a failed file operation ("No space left on device")."""
    return exc.strerror or errno.errorcode.get(exc.errno or 0, str(exc))


class RunLock:
    """An exclusive lock on the run directory for as long as a run writes it (``fcntl.flock``: the
    kernel drops it when the process ends, so a killed run leaves no stale lock)."""

    def __init__(self, out_dir: Path):
        self.path = out_dir / LOCK_FILE
        self._file = None

    def __enter__(self) -> "RunLock":
        import fcntl

        try:
            self._file = self.path.open("a+", encoding="utf-8")
        except OSError as exc:
            raise RunDirectoryError(f"cannot lock {self.path.parent}: {os_reason(exc)}") from exc
        try:
            fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.seek(0)
            holder = self._file.read().strip() or "unknown"
            self._file.close()
            raise RunDirectoryBusy(
                f"{self.path.parent} is in use by another run (pid {holder}); wait for it to finish or choose another --out"
            ) from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(str(os.getpid()))
        self._file.flush()
        return self

    def __exit__(self, *exc_info: Any) -> None:
        import fcntl

        fcntl.flock(self._file.fileno(), fcntl.LOCK_UN)
        self._file.close()


def _record_settings(config_dict: dict[str, Any]) -> dict[str, Any]:
    settings = dict(config_dict)
    settings["run"] = {k: v for k, v in config_dict.get("run", {}).items() if k not in EXECUTION_ONLY}
    return settings


def _read_json(path: Path) -> dict[str, Any]:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise RunDirectoryError(f"{path} is unreadable ({type(exc).__name__}); choose another --out or delete that directory") from exc
    if not isinstance(value, dict):
        raise RunDirectoryError(f"{path} is not a JSON object; choose another --out or delete that directory")
    return value


def check_same_run(out_dir: Path, config: Config, objects_checksum: str, objects_source: str) -> None:
    """Refuse to resume into ``out_dir`` with settings or an object set that would change its records."""
    saved = out_dir / CONFIG_FILE
    if not saved.exists():
        return
    previous = _record_settings(_read_json(saved))
    current = _record_settings(json.loads(json.dumps(config.to_dict())))
    differing = sorted(
        f"{section}.{key}"
        for section in sorted(set(previous) | set(current))
        for key in sorted(set(previous.get(section, {})) | set(current.get(section, {})))
        if previous.get(section, {}).get(key) != current.get(section, {}).get(key)
    )
    if differing:
        raise RunDirectoryMismatch(
            f"{out_dir} holds a run made with other settings ({', '.join(differing)}); choose another --out or delete that directory"
        )
    provenance_path = out_dir / PROVENANCE_FILE
    if provenance_path.exists():
        objects = _read_json(provenance_path).get("objects") or {}
        if objects.get("checksum") != objects_checksum:
            raise RunDirectoryMismatch(
                f"{out_dir} holds a run made with another object set ({objects.get('source')}, now {objects_source}); "
                "choose another --out or delete that directory"
            )


def path_inside(base: Path, name: str) -> Path:
    """``base / name`` for a relative ``name`` that stays inside ``base``; ``ValueError`` for one that would leave it."""
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts or not relative.parts:
        raise ValueError(f"{name!r} is not a path inside {base}")
    return base / relative


def run_file_path(out_dir: Path, name: str) -> Path:
    """The path of a worker's file ``name`` (run-relative) in the run directory; one that would leave it is refused."""
    try:
        return path_inside(out_dir, name)
    except ValueError as exc:
        raise RunDirectoryError(f"refusing to write a file: {exc}") from None


def write_file_atomically(path: Path, contents: bytes) -> None:
    """Write ``path`` whole and synced (a temporary file beside it, then a rename): a reader finds the old
    file or the new one, never part of one. Raises ``RunDirectoryError`` (one line) if the disk refuses."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with temporary.open("wb") as file:
            file.write(contents)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise RunDirectoryError(f"cannot write {path}: {os_reason(exc)}") from exc


def write_json(path: Path, value: Any) -> None:
    """Write a run file whole (temporary file, then rename), as one ``RunDirectoryError`` line if the disk refuses."""
    temporary = path.with_name(path.name + ".tmp")
    try:
        temporary.write_text(json.dumps(value, indent=2, sort_keys=True, default=str), encoding="utf-8")
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise RunDirectoryError(f"cannot write {path}: {os_reason(exc)}") from exc


@dataclass(frozen=True)
class WorkerReport:
    """A worker process just after finishing a unit of work (a study's trial unit; a dataset's object
    plan or chunk of grasps): which process on which node, how many units it has run, its resident
    memory, how long the unit took, and the folder its objects were read from."""

    pid: int
    node: str
    units_done: int
    rss_bytes: int
    unit_s: float
    objects_dir: str | None

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def append_json_line(path: Path, value: dict[str, Any]) -> None:
    """One JSON line appended to ``path`` (a run's ``workers.jsonl``); ``RunDirectoryError`` if it cannot be written."""
    try:
        with path.open("a", encoding="utf-8") as file:
            file.write(json.dumps(value, sort_keys=True) + "\n")
    except OSError as exc:
        raise RunDirectoryError(f"cannot write {path}: {exc.strerror or exc}") from exc

"""The planner's two point-cloud collision checks by two designs, measured on the poses its screens see:

* exact passes: the planner's own (``gripper_occupancy_within``, ``hand_clearance``) and, for the
  hand, one fixed-shape fused pass over (pose, point) (``scene_field.least_separation``);
* a scene representation built once per cloud and queried per pose (``scene_field``): the volume
  from cell balls, the hand from a distance field and balls covering the hand, with the poses the
  bounds leave undecided decided by the planner's exact check.

Per design and check: build time, query time eager and compiled (medians), the share of poses left
undecided, and agreement with the exhaustive reference (``gripper_occupancy``'s count; the exact
``hand_clearance``).
"""
from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import torch

from sagp_batched_kernels import scene_field

from ..config import Config
from ..planning.screens import screen_candidates
from ..robot.hand import DOP_DIRECTIONS
from ..types import PerceivedCloud
from .verdict_agreement import ScreenedPoses

# Cell sizes (metres) of the volume's cell balls.
VOLUME_CELLS_M = (0.008, 0.016)
# The hand's field and balls: (field node spacing, ball tolerance, largest cube side, smallest cube side), metres.
HAND_FIELDS_M = ((0.004, 0.004, 0.016, 0.004), (0.004, 0.008, 0.016, 0.008), (0.004, 0.016, 0.016, 0.016))


def timed(function: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    """The median seconds of ``repeats`` calls of ``function`` after one untimed call (warm-up,
    compilation), and its last result."""
    result = function()
    seconds = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        seconds.append(time.perf_counter() - start)
    return statistics.median(seconds), result


def _row(check: str, design: str, build_s: float | None, eager_s: float, compiled_s: float, decided: torch.Tensor, verdict: torch.Tensor,
         reference: torch.Tensor, fallback_s: tuple[float, float]) -> dict[str, Any]:
    """One table row: times in seconds (``fallback_s``: the exact check on the undecided poses,
    eager and compiled), ``decided``/``verdict``/``reference`` (P,) bool per pose."""
    wrong = int((decided & (verdict != reference)).sum())
    return {
        "check": check, "design": design, "poses": int(reference.numel()), "build_s": build_s, "query_eager_s": eager_s,
        "query_compiled_s": compiled_s, "undecided_share": float((~decided).float().mean()) if decided.numel() else 0.0,
        "decided_disagreements": wrong, "exact_on_undecided_eager_s": fallback_s[0],
        "exact_on_undecided_compiled_s": fallback_s[1],
        "agreement_after_exact": float(((torch.where(decided, verdict, reference)) == reference).float().mean()) if decided.numel() else 1.0,
    }


def volume_rows(poses: ScreenedPoses, repeats: int) -> list[dict[str, Any]]:
    """The volume check by the planner's exact verdict and by cell balls of each ``VOLUME_CELLS_M``."""
    s, row, slot = poses.screened, poses.volume_row, poses.volume_slot
    reference = poses.volume_reference()
    all_decided = torch.ones_like(reference)
    eager_s, exact = timed(lambda: poses.volume_exact(row, slot, False), repeats)
    compiled_s, _ = timed(lambda: poses.volume_exact(row, slot, True), repeats)
    rows = [_row("volume", "exact: gripper_occupancy_within", None, eager_s, compiled_s, all_decided, exact, reference, (0.0, 0.0))]
    points, centre, frames, width = s.occupancy_points[0], s.centre_world[row], poses.rotation[row, slot], s.width_m[row]
    for cell_m in VOLUME_CELLS_M:
        build_s, cells = timed(lambda: scene_field.cell_balls(points, cell_m), repeats)
        eager_s, (upper, lower) = timed(lambda: scene_field.cell_count_bounds(cells, centre, frames, width, poses.geometry), repeats)
        compiled_s, _ = timed(lambda: scene_field.cell_count_bounds(cells, centre, frames, width, poses.geometry, True), repeats)
        limit = poses.limit[row]
        decided = (upper <= limit) | (lower > limit)
        fallback_s = tuple(timed(lambda: poses.volume_exact(row[~decided], slot[~decided], mode), repeats)[0] for mode in (False, True))
        rows.append(_row("volume", f"cell balls {cell_m * 1e3:.0f} mm ({cells.count.numel()} cells)", build_s, eager_s, compiled_s, decided,
                         upper <= limit, reference, fallback_s))
    return rows


def hand_rows(poses: ScreenedPoses, repeats: int) -> list[dict[str, Any]]:
    """The hand sweep by ``hand_clearance``, by the fused exact pass, and by each ``HAND_FIELDS_M`` field."""
    s, index = poses.screened, torch.arange(poses.hand_row.numel())
    row, margin = poses.hand_row, poses.margin_m
    eager_s, reference = timed(lambda: poses.hand_exact(index, False), repeats)
    compiled_s, _ = timed(lambda: poses.hand_exact(index, True), repeats)
    rows = [_row("hand", "exact: hand_clearance", None, eager_s, compiled_s, torch.ones_like(reference), reference, reference, (0.0, 0.0))]
    points, centre, frames = s.hand_check_points[0], s.centre_world[row], poses.rotation[row, poses.hand_slot]
    slack = scene_field.exact_pass_slack(points, centre, poses.low, poses.high)
    separation = (points, centre, frames, DOP_DIRECTIONS, poses.low, poses.high)
    eager_s, least = timed(lambda: scene_field.least_separation(*separation), repeats)
    compiled_s, _ = timed(lambda: scene_field.least_separation(*separation, compile=True), repeats)
    decided = (least < margin - slack) | (least >= margin + slack)
    fallback_s = tuple(timed(lambda: poses.hand_exact(index[~decided], mode), repeats)[0] for mode in (False, True))
    rows.append(_row("hand", "fused exact pass: least_separation", None, eager_s, compiled_s, decided, least < margin, reference, fallback_s))
    for cell_m, tolerance_m, max_side_m, min_side_m in HAND_FIELDS_M:
        def build():
            balls = scene_field.hand_balls(DOP_DIRECTIONS, poses.low, poses.high, margin, tolerance_m, max_side_m, min_side_m)
            return balls, scene_field.distance_field(points, cell_m, float(balls.radius.max()) + cell_m)
        build_s, (balls, field) = timed(build, repeats)
        query = (field, balls, centre, frames, margin, slack)
        eager_s, (lower, upper) = timed(lambda: scene_field.hand_clearance_bounds(*query), repeats)
        compiled_s, _ = timed(lambda: scene_field.hand_clearance_bounds(*query, compile=True), repeats)
        decided = (upper < margin) | (lower >= margin)
        fallback_s = tuple(timed(lambda: poses.hand_exact(index[~decided], mode), repeats)[0] for mode in (False, True))
        design = (f"field {cell_m * 1e3:.0f} mm + {balls.radius.numel()} balls (overshoot <= {max(tolerance_m, 3**0.5 * min_side_m) * 1e3:.0f} mm)")
        rows.append(_row("hand", design, build_s, eager_s, compiled_s, decided, upper < margin, reference, fallback_s))
    return rows


def collision_designs(cloud: PerceivedCloud, config: Config, repeats: int) -> list[dict[str, Any]]:
    """``volume_rows`` and ``hand_rows`` of one cloud, each row tagged with its object."""
    poses = ScreenedPoses(screen_candidates([cloud], config, [0]))
    return [{"object": cloud.object_id, **row} for row in volume_rows(poses, repeats) + hand_rows(poses, repeats)]


def collision_designs_report(clouds: list[PerceivedCloud], config: Config, repeats: int) -> dict[str, Any]:
    """``collision_designs`` of every cloud at ``config``'s pair count, printed as a table; a JSON-ready report."""
    rows = [row for cloud in clouds for row in collision_designs(cloud, config, repeats)]
    print(f"collision designs, {config.planner.n_pairs} pairs, {torch.get_num_threads()} threads, medians of {repeats}; ms; "
          "exact+ = the exact check on the undecided poses, eager/compiled")
    print_designs(rows)
    return {"collision_designs": rows, "pairs": config.planner.n_pairs}


def print_designs(rows: list[dict[str, Any]]) -> None:
    """The rows as a table: milliseconds, undecided share and agreement in per cent."""
    def ms(seconds: float | None) -> str:
        return "-" if seconds is None else f"{seconds * 1e3:.1f}"

    print(f"{'object':<20} {'check':<7} {'design':<56} {'poses':>6} {'build':>7} {'eager':>8} {'compiled':>9} {'undec%':>7} "
          f"{'exact+':>15} {'wrong':>5} {'agree%':>7}")
    for row in rows:
        print(f"{row['object']:<20} {row['check']:<7} {row['design']:<56} {row['poses']:>6} {ms(row['build_s']):>7} {ms(row['query_eager_s']):>8} "
              f"{ms(row['query_compiled_s']):>9} {row['undecided_share'] * 100:>7.2f} {ms(row['exact_on_undecided_eager_s']):>7}/{ms(row['exact_on_undecided_compiled_s']):<7} "
              f"{row['decided_disagreements']:>5} {row['agreement_after_exact'] * 100:>7.2f}", flush=True)

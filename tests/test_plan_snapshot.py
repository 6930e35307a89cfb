"""Which grasps the planner chooses stays what it was recorded choosing: 32 fixed (cloud, seed) plans,
each cloud's chosen candidates (contact point ids, approach, scores, grasp joints) and its
counts against ``plan_snapshot.json``, recorded from the planner before its speed work.

Ids (which fix each grasp's position) and counts are compared exactly; floats within
``SNAPSHOT_ATOL``: approaches and S_geom are functions of the chosen points alone, joints come from the IK, whose float64 closed
form and float32 forward kinematics round alike on one float path and within 1e-6 on another.

Re-record (only where a change of the chosen grasps is intended): ``python tests/test_plan_snapshot.py``.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from planner_clouds import box_surface, cylinder_surface, make_cloud
from recorded import assert_close_to_recorded
from sagp_batched.config import Config
from sagp_batched.planning import plan

SNAPSHOT = Path(__file__).with_name("plan_snapshot.json")
CONFIG = Config().override("planner", n_pairs=3000, max_candidates=24)
TABLE_Z = CONFIG.scene.table_top_z_m
SEEDS = (0, 1, 2, 3)
# Metres for clearances, unitless for approaches and for scores, radians for joints: far above one
# float path's rounding (bit for bit here) and another's (~1e-7), far below a different grasp's.
SNAPSHOT_ATOL = {"approach": 1e-5, "s_geom": 1e-5, "s_reach": 1e-5, "hand_clearance_m": 1e-5, "ik_solution": 1e-4}


def _jittered(points: np.ndarray, normals: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A captured cloud's noise on a constructed one: 0.5 mm on the points, ~3 deg on the normals,
    so that S_geom has few exact ties (whose order another float path could swap)."""
    rng = np.random.default_rng(seed)
    normals = normals + rng.normal(scale=0.05, size=normals.shape)
    return points + rng.normal(scale=0.0005, size=points.shape), normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _handle(body_radius_m: float, base_m: np.ndarray, spacing_m: float = 0.004) -> tuple[np.ndarray, np.ndarray]:
    """The outer half of a torus in the x-z plane beside an upright body: a mug's handle."""
    major, minor, height = 0.03, 0.007, 0.05
    centre = base_m + np.array([body_radius_m, 0.0, height])
    u = np.linspace(-math.pi / 2, math.pi / 2, int(math.pi * major / spacing_m))
    v = np.linspace(0.0, 2 * math.pi, int(2 * math.pi * minor / spacing_m), endpoint=False)
    uu, vv = (grid.ravel() for grid in np.meshgrid(u, v, indexing="ij"))
    ring = np.stack((np.cos(uu), np.zeros_like(uu), np.sin(uu)), axis=1)  # the tube's centre line, radial
    normals = np.cos(vv)[:, None] * ring + np.sin(vv)[:, None] * np.array([0.0, 1.0, 0.0])
    return centre + major * ring + minor * normals, normals


def _lying(points: np.ndarray, normals: np.ndarray, centre_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """An upright cloud turned onto its side (about the world y axis) about ``centre_m``."""
    turn = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    return (points - centre_m) @ turn.T + centre_m, normals @ turn.T


def _half_wall(points: np.ndarray, axis_xy_m: tuple[float, float], gap_m: float) -> np.ndarray:
    """Obstacle points ``gap_m`` outside an upright body's wall on its +x half: a shelf hemming it in."""
    radial = points[:, :2] - np.asarray(axis_xy_m)
    distance = np.linalg.norm(radial, axis=1, keepdims=True)
    side = (np.abs(np.arctan2(radial[:, 1], radial[:, 0])) < math.pi / 2) & (distance[:, 0] > 0.03)
    wall = points[side].copy()
    wall[:, :2] += radial[side] * gap_m / distance[side]
    return wall


def snapshot_clouds():
    """Eight clouds the planner meets: boxes, cans, a can lying down, a mug with a handle, a box
    crowded by another object's points and a can hemmed in by a wall on one side."""
    box = box_surface((0.06, 0.05, 0.15), (0.55, 0.0, TABLE_Z + 0.075))
    wide_box = box_surface((0.09, 0.07, 0.2), (0.5, -0.1, TABLE_Z + 0.1))
    can = cylinder_surface(0.035, 0.1, (0.5, 0.1, TABLE_Z))
    thin_can = cylinder_surface(0.02, 0.18, (0.6, -0.05, TABLE_Z))
    lying = _lying(*cylinder_surface(0.03, 0.14, (0.55, 0.05, TABLE_Z + 0.03)), np.array([0.55, 0.05, TABLE_Z + 0.03]))
    mug_base = np.array([0.55, 0.0, TABLE_Z])
    body, handle = cylinder_surface(0.043, 0.095, mug_base), _handle(0.043, mug_base)
    mug = (np.concatenate((body[0], handle[0])), np.concatenate((body[1], handle[1])))
    neighbour = cylinder_surface(0.035, 0.1, (0.55, 0.085, TABLE_Z))[0]
    named = {"box": box, "wide box": wide_box, "hemmed can": can, "can": can, "thin can": thin_can, "lying can": lying, "mug": mug,
             "crowded box": box}
    clouds = {}
    for index, (name, (points, normals)) in enumerate(named.items()):
        points, normals = _jittered(points, normals, index)
        obstacles = {"crowded box": neighbour, "hemmed can": _half_wall(points, (0.5, 0.1), 0.02)}.get(name)
        clouds[name] = make_cloud(points, normals, name, obstacles=obstacles)
    return clouds


def plan_summary(cloud, seed: int) -> dict:
    """The counts and, per chosen candidate, its contact point ids, approach, scores and grasp joints."""
    result = plan(cloud, CONFIG, seed=seed)
    chosen = result.candidates
    points = cloud.points_world
    ids = (chosen.contacts.reshape(-1, 1, 3) - points[None]).norm(dim=-1).argmin(dim=1).view(-1, 2)
    return {
        "counts": result.counts.as_dict(),
        "ids": ids.tolist(),
        "approach": chosen.approach.tolist(),
        "s_geom": chosen.s_geom.tolist(),
        "s_reach": chosen.s_reach.tolist(),
        "hand_clearance_m": chosen.hand_clearance_m.tolist(),
        "ik_solution": chosen.ik_solution.tolist(),
    }


def _cases():
    return [(name, seed) for name in snapshot_clouds() for seed in SEEDS]


@pytest.fixture(scope="module")
def clouds():
    return snapshot_clouds()


@pytest.fixture(scope="module")
def recorded():
    return json.loads(SNAPSHOT.read_text())


@pytest.mark.recorded
@pytest.mark.parametrize(("name", "seed"), _cases())
def test_the_planner_chooses_the_recorded_grasps(clouds, recorded, name, seed):
    summary = plan_summary(clouds[name], seed)
    expected = recorded[f"{name} seed {seed}"]
    assert summary["counts"] == expected["counts"]
    assert summary["ids"] == expected["ids"]
    floats = {field: summary[field] for field in SNAPSHOT_ATOL}
    assert_close_to_recorded(floats, {field: expected[field] for field in SNAPSHOT_ATOL}, atol=SNAPSHOT_ATOL, label=f"{name} seed {seed}")


def test_the_snapshot_covers_full_short_and_hand_blocked_plans(recorded):
    """The recorded plans hold full candidate lists and short ones, and the swept hand rejects grasps in them."""
    lengths = [len(case["ids"]) for case in recorded.values()]
    assert len(recorded) == 32 and max(lengths) == CONFIG.planner.max_candidates and min(lengths) < CONFIG.planner.max_candidates
    assert all(case["counts"]["rejected_hand"] > 1000 for name, case in recorded.items() if name.startswith(("mug", "hemmed")))


def _rounded(value):
    """Floats to 7 significant digits (float32 carries about 7): the file stays small, the
    rounding (<= 5e-7 rad, 5e-8 m) far inside ``SNAPSHOT_ATOL``."""
    if isinstance(value, float):
        return float(f"{value:.7g}")
    if isinstance(value, list):
        return [_rounded(item) for item in value]
    if isinstance(value, dict):
        return {key: _rounded(item) for key, item in value.items()}
    return value


if __name__ == "__main__":
    torch.set_num_threads(1)
    snapshot_clouds_ = snapshot_clouds()
    cases = {f"{name} seed {seed}": _rounded(plan_summary(snapshot_clouds_[name], seed)) for name, seed in _cases()}
    lines = ",\n".join(f"{json.dumps(key)}: {json.dumps(value, separators=(',', ':'))}" for key, value in cases.items())
    SNAPSHOT.write_text("{\n" + lines + "\n}\n")
    print(f"recorded {len(cases)} plans in {SNAPSHOT}")

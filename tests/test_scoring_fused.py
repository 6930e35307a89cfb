"""SAGP's fused score (SPEC stage 5) on a mug-like cloud with hand-placed candidates."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from sagp_batched.config import GEOMETRY_ONLY_WEIGHTS, Config, ScoreWeights
from sagp_batched.grasps import GraspCandidates
from sagp_batched.rating import PriorRater, ZoneRating, neutral_rating
from sagp_batched.rating.zone_rating import RatingProvenance
from sagp_batched.semantics.scoring import ScoringInputError, score_candidates
from sagp_batched.semantics.zones import decompose
from sagp_batched_kernels.scoring import predicted_swing_tilt, zone_affordance

BASE = np.array([0.5, 0.0, 0.625])
DOWN = [0.0, 0.0, -1.0]
SIDEWAYS = [1.0, 0.0, 0.0]


def mug_zones():
    rng = np.random.default_rng(3)
    theta, z = rng.uniform(0, 2 * math.pi, 4500), rng.uniform(0, 0.08, 4500)
    body = np.stack([0.04 * np.cos(theta), 0.04 * np.sin(theta), z], 1)
    arc, tube = rng.uniform(-math.pi / 2, math.pi / 2, 700), rng.uniform(0, 2 * math.pi, 700)
    ring = 0.032 + 0.006 * np.cos(tube)
    handle = np.stack([0.05 + ring * np.cos(arc), 0.006 * np.sin(tube), 0.04 + ring * np.sin(arc)], 1)
    return decompose(torch.tensor(np.concatenate([body, handle]) + BASE, dtype=torch.float32))


def candidates(midpoints, approaches, closing_axes, s_geom, s_reach=None):
    midpoints = torch.tensor(np.asarray(midpoints) + BASE, dtype=torch.float32)
    closing = torch.tensor(closing_axes, dtype=torch.float32)
    n = midpoints.shape[0]
    zeros = torch.zeros(n)
    return GraspCandidates(
        contacts=torch.stack([midpoints - 0.02 * closing, midpoints + 0.02 * closing], dim=1),
        closing_axis=closing, width_m=torch.full((n,), 0.04), s_geom=torch.tensor(s_geom, dtype=torch.float32),
        approach=torch.tensor(approaches, dtype=torch.float32), rotation=torch.eye(3).repeat(n, 1, 1),
        s_reach=torch.tensor(s_reach if s_reach is not None else [1.0] * n, dtype=torch.float32),
        ik_solution=torch.zeros(n, 7), zone=torch.full((n,), -1, dtype=torch.int64),
        s_afford=zeros, s_avoid=zeros, s_task=zeros, score=zeros,
    )


# Three grasps on the mug: its rim (best geometry), its body, its handle (worst geometry).
RIM, BODY, HANDLE = [0.0, 0.04, 0.079], [-0.04, 0.0, 0.04], [0.088, 0.0, 0.04]


def mug_candidates():
    return candidates(
        [RIM, BODY, HANDLE], [DOWN, SIDEWAYS, SIDEWAYS], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
        s_geom=[0.95, 0.8, 0.6],
    )


def score_zoned(batch, given, weights, zones, config):
    """``batch`` zoned on ``zones`` as the pipeline does, then scored."""
    return score_candidates(zones.zone_candidates(batch), given, weights, zones.centre_of_mass_world, config)


def rating(**fields):
    base = dict(ratings={}, preferred=frozenset(), avoid=frozenset(), approach="any", grasp_style="any",
                max_tilt_deg=None, provenance=RatingProvenance("prior", "test", "v", 0.0, "ok"))
    return ZoneRating(**{**base, **fields})


def test_sagp_ranks_the_mug_handle_first_for_a_functional_grasp_while_go_keeps_geometry_order():
    zones, config = mug_zones(), Config()
    mug_t2 = PriorRater().rate("025_mug", "mug", "t2", np.zeros((4, 4, 3), np.uint8), {})
    sagp = score_zoned(mug_candidates(), mug_t2, config.weights, zones, config)
    go = score_zoned(mug_candidates(), mug_t2, GEOMETRY_ONLY_WEIGHTS, zones, config)
    assert sagp[0].zone == "protrusion_1"
    assert sagp.s_geom.tolist() == pytest.approx([0.6, 0.8, 0.95]), "handle, body, rim"
    assert go.s_geom.tolist() == pytest.approx([0.95, 0.8, 0.6])
    assert torch.allclose(go.score, go.s_geom)


def test_every_weight_enters_the_fused_score():
    zones, config = mug_zones(), Config()
    weights = ScoreWeights(geom=0.3, reach=0.1, afford=0.3, avoid=0.2, task=0.1)
    given = rating(ratings={"top": "dangerous", "middle": "acceptable", "protrusion": "good"}, avoid=frozenset({"top"}))
    scored = score_zoned(mug_candidates(), given, weights, zones, config)
    expected = 0.3 * scored.s_geom + 0.1 * scored.s_reach + 0.3 * scored.s_afford - 0.2 * scored.s_avoid + 0.1 * scored.s_task
    assert torch.allclose(scored.score, expected)
    by_geom = {round(float(g), 2): i for i, g in enumerate(scored.s_geom)}
    rim, body, handle = by_geom[0.95], by_geom[0.8], by_geom[0.6]
    assert scored.s_afford[handle] == 1.0 and scored.s_afford[body] == 0.5 and scored.s_afford[rim] == -1.0
    assert scored.s_avoid.tolist()[rim] == 1.0 and scored.s_avoid[[body, handle]].sum() == 0.0
    for name, value in dataclasses.asdict(weights).items():
        changed = score_zoned(mug_candidates(), given, dataclasses.replace(weights, **{name: value + 1.0}), zones, config)
        assert not torch.allclose(changed.score.sort().values, scored.score.sort().values), f"weight {name} has no effect"


def test_an_avoided_zone_is_penalised_by_its_weight():
    zones, config = mug_zones(), Config()
    plain = score_zoned(mug_candidates(), rating(), config.weights, zones, config)
    avoided = score_zoned(mug_candidates(), rating(avoid=frozenset({"top"})), config.weights, zones, config)
    rim_plain = plain.score[plain.s_geom.argmax()]
    rim_avoided = avoided.score[avoided.s_geom.argmax()]
    assert float(rim_plain - rim_avoided) == pytest.approx(config.weights.avoid)
    assert avoided.s_geom[0] != pytest.approx(0.95), "the avoided rim is no longer first"


def test_neutral_rating_ranks_by_geometry_and_reach_alone():
    zones, config = mug_zones(), Config()
    batch = candidates([RIM, BODY, HANDLE], [DOWN] * 3, [[1.0, 0.0, 0.0]] * 3, s_geom=[0.6, 0.9, 0.8], s_reach=[1.0, 0.6, 0.9])
    neutral = neutral_rating("prior", "zone_priors.json", "prior-1", 0.0, "unknown object")
    scored = score_zoned(batch, neutral, config.weights, zones, config)
    assert (scored.s_afford == 0).all() and (scored.s_avoid == 0).all() and (scored.s_task == 1).all()
    expected_order = torch.argsort(0.3 * batch.s_geom + 0.1 * batch.s_reach, descending=True)
    assert torch.equal(scored.s_geom, batch.s_geom[expected_order])


def test_danger_dominates_a_point_in_several_rated_zones():
    memberships = torch.tensor([[True, False, True], [False, True, True], [False, False, False]])
    phi = torch.tensor([-1.0, 1.0, 0.5])
    rated = torch.tensor([True, True, True])
    assert zone_affordance(memberships, phi, rated).tolist() == [-1.0, 1.0, 0.0]
    assert zone_affordance(memberships, phi, torch.tensor([False, True, False])).tolist() == [0.0, 1.0, 0.0]


def test_a_handle_point_in_the_top_third_is_rated_as_the_handle_not_as_the_rim():
    zones, config = mug_zones(), Config()
    upper_handle = [0.05 + 0.038 * math.cos(math.pi / 6), 0.0, 0.04 + 0.038 * math.sin(math.pi / 6)]  # outer surface
    batch = candidates([upper_handle, RIM], [SIDEWAYS, DOWN], [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], s_geom=[0.6, 0.9])
    members = zones.memberships[zones.nearest_points(batch.position)][0]
    assert members[zones.zone_names.index("protrusion_1")] and members[zones.zone_names.index("top")], "premise: handle point in the top third"
    handle_grasp = zones.zone_candidates(batch)[0]
    assert handle_grasp.zones[0] == "protrusion_1" and "top" not in handle_grasp.zones
    given = rating(ratings={"top": "dangerous", "protrusion": "good"}, avoid=frozenset({"top"}))
    scored = score_zoned(batch, given, config.weights, zones, config)
    handle, rim = in_geometric_order(scored, "s_afford")[1], in_geometric_order(scored, "s_afford")[0]
    assert (handle, rim) == (1.0, -1.0)
    assert in_geometric_order(scored, "s_avoid") == [1.0, 0.0]
    # A side zone's rating still reaches the handle point: danger dominates.
    side = "left" if members[zones.zone_names.index("left")] else "right"
    sided = score_zoned(batch, rating(ratings={"protrusion": "good", side: "dangerous"}), config.weights, zones, config)
    assert in_geometric_order(sided, "s_afford")[1] == -1.0


def in_geometric_order(scored, field_name):
    """``field_name`` of ``scored`` (ranked by score) back in the candidates' original, S_geom-descending order."""
    return getattr(scored, field_name)[torch.argsort(scored.s_geom, descending=True)].tolist()


def test_task_term_needs_the_prescribed_approach_within_30_degrees():
    zones, config = mug_zones(), Config()
    tilted = [math.sin(math.radians(25)), 0.0, -math.cos(math.radians(25))]
    too_tilted = [math.sin(math.radians(35)), 0.0, -math.cos(math.radians(35))]
    batch = candidates([RIM, RIM, RIM, BODY], [DOWN, tilted, too_tilted, SIDEWAYS], [[0.0, 1.0, 0.0]] * 4, s_geom=[0.9, 0.8, 0.7, 0.6])
    top = score_zoned(batch, rating(approach="top"), config.weights, zones, config)
    assert in_geometric_order(top, "s_task") == [1.0, 1.0, 0.0, 0.0]
    side = score_zoned(batch, rating(approach="side"), config.weights, zones, config)
    assert in_geometric_order(side, "s_task") == [0.0, 0.0, 0.0, 1.0]
    front = score_zoned(batch, rating(approach="front"), config.weights, zones, config)
    assert in_geometric_order(front, "s_task") == [0.0, 0.0, 0.0, 1.0], "the front faces the robot: the gripper moves along +x"
    anywhere = score_zoned(batch, rating(approach="any"), config.weights, zones, config)
    assert (anywhere.s_task == 1).all()


def test_task_term_needs_the_predicted_tilt_within_the_constraint():
    zones, config = mug_zones(), Config()
    # Both grasps close along y; the one across the body's centre holds the mug level, the handle grasp
    # leaves its centre of mass ~8 cm off the closing axis, so the mug swings.
    across_body = [0.0, 0.0, 0.04]
    batch = candidates([across_body, HANDLE], [SIDEWAYS, SIDEWAYS], [[0.0, 1.0, 0.0]] * 2, s_geom=[0.9, 0.8])
    upright = score_zoned(batch, rating(approach="side", max_tilt_deg=15.0), config.weights, zones, config)
    by_geom = {round(float(g), 1): float(t) for g, t in zip(upright.s_geom, upright.s_task)}
    assert by_geom == {0.9: 1.0, 0.8: 0.0}
    free = score_zoned(batch, rating(approach="side"), config.weights, zones, config)
    assert (free.s_task == 1).all()


def test_swing_tilt_predictor():
    up = torch.tensor([0.0, 0.0, 1.0])
    centre_of_mass = torch.tensor([0.0, 0.0, 0.0])
    grasp = torch.tensor([[0.0, 0.0, 0.05], [0.05, 0.0, 0.0], [0.05, 0.0, 0.0], [0.01, 0.0, 0.0]])
    closing = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
    tilt = predicted_swing_tilt(grasp, closing, centre_of_mass, up, friction_hold_offset_m=0.02)
    # Above the CoM: hangs already; 5 cm beside a horizontal axis: swings 90 deg; vertical axis: gravity has
    # no lever about it; 1 cm beside: friction holds.
    assert torch.allclose(tilt, torch.tensor([0.0, math.pi / 2, 0.0, 0.0]), atol=1e-5)


def test_unzoned_candidates_and_a_missing_centre_of_mass_are_named():
    zones, config = mug_zones(), Config()
    with pytest.raises(ScoringInputError, match="zones"):
        score_candidates(mug_candidates(), rating(), config.weights, zones.centre_of_mass_world, config)
    empty_zones = decompose(torch.zeros(0, 3))
    with pytest.raises(ScoringInputError, match="empty"):
        score_zoned(mug_candidates(), rating(max_tilt_deg=15.0), config.weights, empty_zones, config)
    unzoned = score_zoned(mug_candidates(), rating(ratings={"top": "good"}), config.weights, empty_zones, config)
    assert (unzoned.s_afford == 0).all() and (unzoned.zone == -1).all()


def test_a_rating_that_calls_protrusion_2_dangerous_moves_grasps_off_it_while_protrusion_still_rates_both():
    """A body with a handle (protrusion_1) and a smaller spout (protrusion_2): "protrusion: good"
    rates both, so the spout's better geometry wins; calling protrusion_2 dangerous sends the
    grasp to the handle."""
    rng = np.random.default_rng(5)
    theta, z = rng.uniform(0, 2 * math.pi, 5000), rng.uniform(0, 0.16, 5000)
    body = np.stack([0.05 * np.cos(theta), 0.05 * np.sin(theta), z], 1)
    arc, tube = rng.uniform(-math.pi / 2, math.pi / 2, 900), rng.uniform(0, 2 * math.pi, 900)
    ring = 0.04 + 0.007 * np.cos(tube)
    handle = np.stack([0.06 + ring * np.cos(arc), 0.007 * np.sin(tube), 0.08 + ring * np.sin(arc)], 1)
    spout = np.stack([-rng.uniform(0.05, 0.085, 300), rng.uniform(-0.01, 0.01, 300), rng.uniform(0.13, 0.16, 300)], 1)
    zones = decompose(torch.tensor(np.concatenate([body, handle, spout]) + BASE, dtype=torch.float32))
    config = Config()
    on_handle, on_spout = [0.1, 0.0, 0.08], [-0.08, 0.0, 0.145]
    batch = candidates([on_handle, on_spout], [SIDEWAYS, DOWN], [[0.0, 1.0, 0.0], [0.0, 1.0, 0.0]], s_geom=[0.6, 0.9])
    handle_zone, spout_zone = (zones.zone_names[int(i)] for i in zones.candidate_zones(batch.position)[0])
    assert (handle_zone, spout_zone) == ("protrusion_1", "protrusion_2")
    both_good = score_zoned(batch, rating(ratings={"protrusion": "good"}), config.weights, zones, config)
    assert torch.allclose(both_good.s_afford, torch.ones(2)) and both_good.candidate_id[0] == 1
    spout_dangerous = rating(ratings={"protrusion": "good", "protrusion_2": "dangerous"})
    moved = score_zoned(batch, spout_dangerous, config.weights, zones, config)
    assert moved.candidate_id[0] == 0 and moved.s_afford.tolist() == [1.0, -1.0]
    assert spout_dangerous.level("protrusion_1") == "good" and spout_dangerous.level("protrusion_2") == "dangerous"

"""Functional-region annotations: they sit on the object's own parts, and FRA/FAR are counted from them."""
import json

import numpy as np
import pytest

from sagp_batched.study.metrics import per_object, summarise
from sagp_batched.study.study_report import RATE_METRICS, summary_markdown, write_plots
from sagp_batched.world.functional_regions import load_regions, mesh_vertices, region_membership
from sagp_batched.world.objects import YCB_ASYMMETRIC_IDS

REGIONS = load_regions()
SLACK_M = 0.01


def _mug_parts(ycb_dir):
    """The mug's handle and rim vertices, found from the mesh alone: the rim is the top 5 mm, the body
    axis the centre of the rim's x-y extent, the body radius the median radial distance at mid-height,
    and the handle everything below the rim more than 3 mm outside that radius."""
    vertices = mesh_vertices(ycb_dir / "025_mug" / "textured.obj")
    top = vertices[:, 2].max()
    rim = vertices[vertices[:, 2] > top - 0.005]
    axis_xy = (rim[:, :2].min(axis=0) + rim[:, :2].max(axis=0)) / 2
    radial = np.linalg.norm(vertices[:, :2] - axis_xy, axis=1)
    mid_height = np.abs(vertices[:, 2] - top / 2) < 0.01
    body_radius = np.median(radial[mid_height])
    handle = vertices[(radial > body_radius + 0.003) & (vertices[:, 2] < top - 0.005)]
    return handle, rim


def test_the_mug_handle_lies_in_its_functional_region_and_not_its_avoid_region(ycb_dir):
    handle, _ = _mug_parts(ycb_dir)
    # A fraction, not a count: the embedded compact meshes hold a fifth of the full ones' vertices.
    n_vertices = len(mesh_vertices(ycb_dir / "025_mug" / "textured.obj"))
    assert len(handle) > 0.02 * n_vertices, "the mesh should show a handle outside the body"
    membership = region_membership("025_mug", handle)
    assert membership["in_functional_region"].mean() >= 0.9
    assert membership["in_avoid_region"].mean() <= 0.05


def test_the_mug_rim_lies_in_its_avoid_region_and_not_its_functional_region(ycb_dir):
    _, rim = _mug_parts(ycb_dir)
    membership = region_membership("025_mug", rim)
    assert membership["in_avoid_region"].mean() >= 0.9
    assert not membership["in_functional_region"].any()


def test_every_asymmetric_study_object_is_annotated_with_both_regions_and_a_method():
    assert YCB_ASYMMETRIC_IDS <= set(REGIONS)
    for regions in REGIONS.values():
        assert regions.functional and regions.avoid and regions.functional_reason and regions.avoid_reason
    from importlib import resources

    table = json.loads(resources.files("sagp_batched").joinpath("data/functional_regions.json").read_text())
    assert len(table["method"]) > 200


@pytest.mark.parametrize("object_id", sorted(REGIONS))
def test_every_box_is_ordered_on_the_object_and_the_two_regions_do_not_overlap(ycb_dir, object_id):
    vertices = mesh_vertices(ycb_dir / object_id / "textured.obj")
    low, high = vertices.min(axis=0) - SLACK_M, vertices.max(axis=0) + SLACK_M
    regions = REGIONS[object_id]
    for box in regions.functional + regions.avoid:
        assert np.all(np.less(box.min, box.max)), box
        assert np.all(np.asarray(box.min) >= low) and np.all(np.asarray(box.max) <= high), box
        assert box.contains(vertices).sum() >= max(3, 0.0025 * len(vertices)), f"{box} covers almost none of the mesh"
    for functional in regions.functional:
        for avoid in regions.avoid:
            overlap = np.minimum(functional.max, avoid.max) - np.maximum(functional.min, avoid.min)
            assert not np.all(overlap > 0), (functional, avoid)


def _table(**objects):
    return {"method": "hand-placed boxes", "objects": objects}


GOOD_REGION = {"reason": "held here", "boxes": [{"min": [0, 0, 0], "max": [0.01, 0.01, 0.01]}]}


@pytest.mark.parametrize("entry, field", [
    ({"functional": GOOD_REGION}, "avoid"),
    ({"functional": GOOD_REGION, "avoid": {"reason": "", "boxes": GOOD_REGION["boxes"]}}, "avoid"),
    ({"functional": {"reason": "x", "boxes": [{"min": [0, 0, 0.02], "max": [0.01, 0.01, 0.01]}]}, "avoid": GOOD_REGION}, "functional"),
    ({"functional": {"reason": "x", "boxes": [{"min": [0, 0], "max": [0.01, 0.01, 0.01]}]}, "avoid": GOOD_REGION}, "functional"),
    ({"functional": {"reason": "x", "boxes": []}, "avoid": GOOD_REGION}, "functional"),
])
def test_a_malformed_annotation_is_a_one_line_value_error_naming_the_object_and_field(tmp_path, entry, field):
    path = tmp_path / "regions.json"
    path.write_text(json.dumps(_table(**{"999_widget": entry})))
    with pytest.raises(ValueError) as raised:
        load_regions(path)
    message = str(raised.value)
    assert "999_widget" in message and field in message and "\n" not in message


def test_a_table_without_a_method_is_rejected(tmp_path):
    path = tmp_path / "regions.json"
    path.write_text(json.dumps({"objects": {}}))
    with pytest.raises(ValueError, match="method"):
        load_regions(path)


def test_membership_is_none_for_an_unannotated_object_and_per_point_for_an_annotated_one():
    assert region_membership("005_tomato_soup_can", np.zeros(3)) == {"in_functional_region": None, "in_avoid_region": None}
    handle_centre, rim_point = [-0.045, 0.0, 0.04], [0.052, 0.0, 0.078]
    assert region_membership("025_mug", np.array(handle_centre)) == {"in_functional_region": True, "in_avoid_region": False}
    both = region_membership("025_mug", np.array([handle_centre, rim_point]))
    assert both["in_functional_region"].tolist() == [True, False] and both["in_avoid_region"].tolist() == [False, True]


def _record(obj, success, functional, avoid, method="sagp"):
    return {"object": obj, "category": "containers", "asymmetric": functional is not None, "task": "t2", "method": method,
            "trial": 0, "success": success, "task_success": success, "in_preferred_zone": True, "in_avoid_zone": False,
            "in_functional_region": functional, "in_avoid_region": avoid, "orientation_kept": True, "attempt_log": [],
            "times_s": {}}


RECORDS = [
    _record("025_mug", True, True, False),
    _record("025_mug", True, False, True),
    _record("025_mug", False, True, False),  # failed grasp: out of both denominators
    _record("037_scissors", True, True, False),
    _record("005_tomato_soup_can", True, None, None),  # unannotated: out of both denominators
    _record("025_mug", True, False, False, method="go"),
]


def test_fra_and_far_count_only_successful_grasps_on_annotated_objects():
    metrics = summarise(RECORDS)["sagp"]["t2"]["all"]
    assert metrics["counts"]["FRA"] == [2, 3] and metrics["counts"]["FAR"] == [1, 3]
    assert metrics["FRA"] == pytest.approx(2 / 3) and metrics["ci95"]["FRA"] is not None
    assert metrics["counts"]["GSR"] == [4, 5]
    assert summarise(RECORDS)["go"]["t2"]["all"]["counts"]["FAR"] == [0, 1]


def test_the_report_has_fra_and_far_columns_and_an_fra_by_object_table(tmp_path):
    markdown = summary_markdown(summarise(RECORDS), {}, by_object=per_object(RECORDS))
    lines = markdown.splitlines()
    assert lines[lines.index("## Task t2") + 2].startswith("| method | trials | errors | GSR | FAS | TSR | PZA | AC | OP | FRA | FAR |")
    start = lines.index("### Task t2 FRA by object") + 2
    end = next((i for i in range(start, len(lines)) if not lines[i].startswith("|")), len(lines))
    table = lines[start:end]
    assert table[0] == "| object | Geometry-Only FRA | SAGP FRA |"
    assert table[2] == "| 025_mug | 0/1 (0.0 %) | 1/2 (50.0 %) |"
    assert table[3] == "| 037_scissors | - | 1/1 (100.0 %) |"
    assert len(table) == 4, "only annotated objects get a row"
    assert RATE_METRICS[-2:] == ("FRA", "FAR")
    assert all(path.stat().st_size > 0 for path in write_plots(tmp_path, summarise(RECORDS)))

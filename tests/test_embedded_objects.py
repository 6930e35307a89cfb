"""The published YCB objects ship inside the package: a default run needs no ../shared and no $SAGP_YCB_DIR."""
from __future__ import annotations

import json

import numpy as np
import pybullet
import pytest

from sagp_batched.world.objects import EMBEDDED_YCB_SOURCE, YCB_ASYMMETRIC_IDS, YCB_DIR_ENV, embedded_ycb_dir, load_object_set

from ycb_paths import FULL_YCB_DIR, HAVE_FULL_YCB

STUDY_IDS = {
    "002_master_chef_can", "003_cracker_box", "005_tomato_soup_can", "006_mustard_bottle", "007_tuna_fish_can",
    "010_potted_meat_can", "011_banana", "019_pitcher_base", "021_bleach_cleanser", "025_mug", "035_power_drill",
    "037_scissors", "040_large_marker", "051_large_clamp",
}
DISTRACTOR_IDS = {"004_sugar_box", "008_pudding_box", "009_gelatin_box", "024_bowl", "061_foam_brick", "013_apple", "017_orange"}
MAX_EMBEDDED_BYTES = 12_000_000
BOUNDING_BOX_TOLERANCE_M = 0.002


def _mesh_bounds(obj_path) -> np.ndarray:
    """(2, 3) lower and upper corner of an OBJ's vertices, metres, in the object's link frame."""
    with open(obj_path) as lines:
        vertices = np.array([[float(x) for x in line.split()[1:4]] for line in lines if line.startswith("v ")])
    return np.stack([vertices.min(axis=0), vertices.max(axis=0)])


@pytest.fixture(scope="module")
def embedded():
    return load_object_set(embedded_ycb_dir())


def test_embedded_set_holds_the_14_study_objects_and_7_distractors(embedded):
    assert {spec.id for spec in embedded.targets()} == STUDY_IDS
    assert {spec.id for spec in embedded.distractors()} == DISTRACTOR_IDS
    assert {spec.id for spec in embedded.targets() if spec.asymmetric} == YCB_ASYMMETRIC_IDS


def test_default_object_set_without_env_is_the_embedded_compact_ycb(monkeypatch, embedded):
    monkeypatch.delenv(YCB_DIR_ENV, raising=False)
    default = load_object_set(None)
    assert default.source.startswith(f"{EMBEDDED_YCB_SOURCE}:")
    assert default.ids == embedded.ids
    assert all(default.get(i).urdf_path == embedded.get(i).urdf_path for i in default.ids)


def test_embedded_data_is_under_12_mb_and_records_how_it_was_made():
    root = embedded_ycb_dir()
    total = sum(path.stat().st_size for path in root.rglob("*") if path.is_file())
    assert total < MAX_EMBEDDED_BYTES, f"embedded YCB data is {total / 1e6:.1f} MB"
    compact = json.loads((root / "objects.json").read_text())["compact"]
    assert {"source", "target_faces", "texture_size_px", "jpeg_quality", "pymeshlab_version"} <= compact.keys()
    assert "CC BY 4.0" in (root / "README.md").read_text()


def test_every_embedded_urdf_loads_in_pybullet_with_its_visual_mesh(embedded):
    client = pybullet.connect(pybullet.DIRECT)
    try:
        for spec in embedded.targets() + embedded.distractors():
            body = pybullet.loadURDF(str(spec.urdf_path), flags=pybullet.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
            assert pybullet.getDynamicsInfo(body, -1, physicsClientId=client)[0] == pytest.approx(spec.mass_kg)
            assert pybullet.getVisualShapeData(body, physicsClientId=client), f"{spec.id} has no visual shape"
    finally:
        pybullet.disconnect(client)


@pytest.mark.skipif(not HAVE_FULL_YCB, reason=f"full-resolution YCB set not found at {FULL_YCB_DIR}")
def test_compact_meshes_keep_the_full_resolution_bounding_box_within_2mm(embedded):
    full = load_object_set(FULL_YCB_DIR)
    for spec in embedded.targets() + embedded.distractors():
        compact_bounds = _mesh_bounds(spec.urdf_path.parent / "textured.obj")
        full_bounds = _mesh_bounds(full.get(spec.id).urdf_path.parent / "textured.obj")
        error = np.abs(compact_bounds - full_bounds).max()
        assert error <= BOUNDING_BOX_TOLERANCE_M, f"{spec.id}: bounding box differs by {error * 1000:.2f} mm"

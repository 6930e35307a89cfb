"""Collision hulls measured against the mesh they stand for: the figures on known shapes, and an imported cup that
keeps its cavity, with its figures in its metadata and ObjectSpec, and an object past a bound flagged and kept."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from scipy.spatial import ConvexHull

from sagp_batched.world import mesh_import
from sagp_batched.world.hull_fidelity import hull_fidelity
from sagp_batched.world.mesh_decompose import coacd_hulls
from sagp_batched.world.mesh_files import _read_obj_parts
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import load_object_set

# The cup: outer radius, inner radius, height, base thickness (m); a 5 mm wall.
CUP_R, CUP_INNER_R, CUP_H, CUP_BASE = 0.03, 0.025, 0.07, 0.006
# Cavity points stay this far from the inner wall and base: a hull of a curved wall piece bulges inward by its chord's
# sagitta (under a millimetre for the pieces CoACD cuts a 5 cm bore into).
CAVITY_MARGIN_M = 0.002
# Quasi-random volume samples resolve the union's volume to a few tenths of a percent of the bounding box's.
RATIO_TOLERANCE = 0.01


def _cup() -> trimesh.Trimesh:
    """An open-top cup: a closed surface of revolution (outer wall, rim, inner wall, floor, base)."""
    profile = np.array([[0.0, 0.0], [CUP_R, 0.0], [CUP_R, CUP_H], [CUP_INNER_R, CUP_H], [CUP_INNER_R, CUP_BASE], [0.0, CUP_BASE]])
    return trimesh.creation.revolve(profile, sections=48)


def _l_shape() -> tuple[trimesh.Trimesh, trimesh.Trimesh]:
    bar = trimesh.creation.box([0.06, 0.02, 0.02])
    post = trimesh.creation.box([0.02, 0.02, 0.04])
    post.apply_translation([0.02, 0.0, 0.03])
    return bar, post


def _inside_any(points: np.ndarray, hulls: list[trimesh.Trimesh]) -> np.ndarray:
    inside = np.zeros(len(points), dtype=bool)
    for hull in hulls:
        planes = ConvexHull(hull.vertices).equations
        inside |= (points @ planes[:, :3].T + planes[:, 3]).max(axis=1) <= 0.0
    return inside


def _metadata(spec) -> dict:
    return json.loads((spec.urdf_path.parent / "metadata.json").read_text())


def test_a_box_standing_for_itself_fits_exactly():
    box = trimesh.creation.box([0.05, 0.03, 0.02])
    fidelity = hull_fidelity(box, [box])
    assert fidelity.volume_ratio == pytest.approx(1.0, abs=RATIO_TOLERANCE)
    assert fidelity.max_hull_to_mesh_distance_m < 1e-6 and fidelity.mesh_volume_from == "mesh"


def test_an_l_shapes_convex_hull_adds_the_corner_triangle_and_strays_by_its_known_distance():
    bar, post = _l_shape()
    l_shape = trimesh.util.concatenate([bar, post])
    fidelity = hull_fidelity(l_shape, [l_shape.convex_hull])
    # In the xz-plane the hull adds the triangle (-0.03, 0.01), (0.01, 0.01), (0.01, 0.05): 0.0008 m^2 over the
    # L's 0.002 m^2, the depth (y) being the same; its slanted face is furthest from the L at x = -0.01, 2 cm off.
    assert fidelity.volume_ratio == pytest.approx(1.4, abs=RATIO_TOLERANCE)
    assert fidelity.max_hull_to_mesh_distance_m == pytest.approx(0.02, abs=2e-4)
    exact = hull_fidelity(l_shape, [bar, post])
    assert exact.volume_ratio == pytest.approx(1.0, abs=RATIO_TOLERANCE) and exact.max_hull_to_mesh_distance_m < 1e-6


def test_the_faces_two_hulls_share_inside_a_solid_are_no_excess():
    # A thick block cut in two: the cut face's centre is 1.5 cm from the block's surface, but it is inside the block.
    block = trimesh.creation.box([0.04, 0.03, 0.03])
    halves = [trimesh.creation.box([0.02, 0.03, 0.03]) for _ in range(2)]
    halves[0].apply_translation([-0.01, 0.0, 0.0])
    halves[1].apply_translation([0.01, 0.0, 0.0])
    assert hull_fidelity(block, halves).max_hull_to_mesh_distance_m < 1e-6


def test_an_open_mesh_is_measured_against_its_convex_hulls_volume():
    tumbler = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=24)
    top = tumbler.face_normals[:, 2] > 0.99
    open_tumbler = trimesh.Trimesh(tumbler.vertices, tumbler.faces[~top])
    fidelity = hull_fidelity(open_tumbler, [tumbler])
    assert fidelity.mesh_volume_from == "convex hull" and fidelity.volume_ratio == pytest.approx(1.0, abs=RATIO_TOLERANCE)


@pytest.fixture(scope="module")
def cup_import(tmp_path_factory):
    root = tmp_path_factory.mktemp("cup") / "objects"
    root.mkdir()
    _cup().export(root / "cup.obj")
    settings = MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache"))
    return root, settings, load_object_set(root, import_settings=settings).get("cup")


def test_a_cup_imported_with_the_default_decomposer_keeps_its_cavity(cup_import):
    _, settings, spec = cup_import
    record = spec.import_record
    assert record.decomposer == "coacd" and record.fidelity_ok and record.fidelity_issues == ()
    assert record.hull_volume_ratio <= settings.max_hull_volume_ratio
    assert record.hull_max_distance_m <= settings.max_hull_distance_m
    hulls = _read_obj_parts(spec.urdf_path.parent / "collision.obj")
    assert len(hulls) == record.collision_hulls
    # Points filling the cavity, in the cup's own frame, moved into the link frame with the record's map.
    rng = np.random.default_rng(0)
    radius = (CUP_INNER_R - CAVITY_MARGIN_M) * np.sqrt(rng.random(2000))
    angle = rng.random(2000) * 2 * np.pi
    height = rng.uniform(CUP_BASE + CAVITY_MARGIN_M, CUP_H, 2000)
    cavity = np.column_stack([radius * np.cos(angle), radius * np.sin(angle), height, np.ones(2000)])
    in_link = (record.link_from_source @ cavity.T).T[:, :3]
    assert not _inside_any(in_link, hulls).any()


def test_the_fidelity_figures_and_the_source_map_reach_metadata_and_the_spec(cup_import):
    _, _, spec = cup_import
    metadata, record = _metadata(spec), spec.import_record
    assert record.hull_volume_ratio == metadata["hull_volume_ratio"] and record.hull_max_distance_m == metadata["hull_max_distance_m"]
    assert metadata["hull_ratio_volume_from"] == "mesh" and metadata["format"] == mesh_import.IMPORT_FORMAT
    assert np.allclose(record.link_from_source, np.array(metadata["source_to_link"]), atol=1e-15)  # the cup is in metres
    assert record.com_m == pytest.approx(metadata["com_m"])
    # The cup's centre of mass, on its axis, lands where the link frame puts it.
    source_com = np.append(_cup().center_mass, 1.0)
    assert np.allclose((record.link_from_source @ source_com)[:3], record.com_m, atol=1e-6)


def test_an_object_past_a_bound_is_flagged_and_kept_and_the_bounds_rebuild_nothing(cup_import, monkeypatch):
    root, settings, spec = cup_import

    def no_build(*args, **kwargs):
        raise AssertionError("a cached object was built again for a bound that changes no file")

    monkeypatch.setattr(mesh_import, "_build", no_build)
    strict = MeshImportSettings(cache_dir=settings.cache_dir, max_hull_volume_ratio=1.0001, max_hull_distance_m=1e-6)
    flagged = load_object_set(root, import_settings=strict).get("cup")
    assert flagged.urdf_path == spec.urdf_path and not flagged.import_record.fidelity_ok
    assert len(flagged.import_record.fidelity_issues) == 2
    assert "over 1.00x" in flagged.import_record.fidelity_issues[0] and "mm outside its mesh" in flagged.import_record.fidelity_issues[1]


def test_vhacds_hulls_fill_a_cup_and_the_cup_is_flagged_not_skipped(tmp_path):
    root = tmp_path / "objects"
    root.mkdir()
    _cup().export(root / "cup.obj")
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", decomposer="vhacd", vhacd_resolution=20_000)
    objects = load_object_set(root, import_settings=settings)
    record = objects.get("cup").import_record
    assert objects.ids == ("cup",) and not objects.skipped
    assert record.decomposer == "vhacd" and not record.fidelity_ok and record.hull_volume_ratio > settings.max_hull_volume_ratio


def test_coacd_gives_the_same_hulls_every_time(tmp_path):
    cup = _cup()
    settings = MeshImportSettings(cache_dir=tmp_path)
    first, second = coacd_hulls(cup, settings), coacd_hulls(cup, settings)
    assert len(first) == len(second) and all(np.array_equal(a.vertices, b.vertices) for a, b in zip(first, second))


def test_settings_refuse_bounds_and_coacd_values_that_mean_nothing():
    for bad in (dict(max_hull_volume_ratio=0.0), dict(max_hull_distance_m=-1.0), dict(max_convex_hulls=0),
                dict(coacd_preprocess_mode="sometimes"), dict(coacd_input_faces=2), dict(coacd_max_hull_vertices=3)):
        with pytest.raises(ValueError, match="MeshImportSettings"):
            MeshImportSettings(**bad)

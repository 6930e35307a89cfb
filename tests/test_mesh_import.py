"""A folder of meshes or URDFs is an object set: URDFs, collision hulls, mass, inertia and resting poses made by code."""
from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pybullet
import pytest
import trimesh

from sagp_batched import Config
from sagp_batched.world import mesh_decompose, mesh_import
from sagp_batched.world.mesh_import import CACHE_DIR_ENV
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import ObjectSetError, embedded_ycb_dir, load_object_set
from sagp_batched.world.scene import Scene

# V-HACD at a low resolution: a second or two per concave test object.
QUICK = dict(decomposer="vhacd", vhacd_resolution=20_000)
BOX_EXTENTS_M = (0.05, 0.03, 0.02)
BLOB_URDF_SCALE = 0.5
GIVEN_MASS_KG = 0.3
GIVEN_FRICTION = 0.6


def _mug() -> trimesh.Trimesh:
    """A 6 cm cup (walls, bottom) with a block handle on its +x side: concave, 8.5 cm long. Its parts are closed
    surfaces that share no vertex (a gap of a tenth of a millimetre), so the whole is watertight."""
    wall = trimesh.creation.annulus(r_min=0.026, r_max=0.03, height=0.08)
    wall.apply_translation([0.0, 0.0, 0.04])
    bottom = trimesh.creation.cylinder(radius=0.0259, height=0.005)
    bottom.apply_translation([0.0, 0.0, 0.0025])
    handle = trimesh.creation.box([0.012, 0.01, 0.05])
    handle.apply_translation([0.0366, 0.0, 0.045])
    return trimesh.util.concatenate([wall, bottom, handle])


def _parts() -> list[trimesh.Trimesh]:
    base = trimesh.creation.box([0.04, 0.04, 0.02])
    post = trimesh.creation.cylinder(radius=0.015, height=0.04)
    post.apply_translation([0.0, 0.0, 0.03])
    return [base, post]


def _blob() -> trimesh.Trimesh:
    return trimesh.creation.capsule(height=0.06, radius=0.025)


BLOB_URDF = f"""<robot name="blob">
  <link name="blob_link">
    <inertial><origin xyz="0 0 0"/><mass value="0.1"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="0"/></inertial>
    <visual>
      <origin rpy="1.5707963 0 0.3" xyz="0.1 0 0"/>
      <geometry><mesh filename="blob.obj" scale="{BLOB_URDF_SCALE} {BLOB_URDF_SCALE} {BLOB_URDF_SCALE}"/></geometry>
      <material name="blue"><color rgba="0.1 0.2 0.9 1"/></material>
    </visual>
    <collision><geometry><mesh filename="blob.obj" scale="{BLOB_URDF_SCALE} {BLOB_URDF_SCALE} {BLOB_URDF_SCALE}"/></geometry></collision>
  </link>
</robot>
"""


def _make_folder(root: Path) -> Path:
    root.mkdir(parents=True)
    trimesh.creation.box(BOX_EXTENTS_M).export(root / "box.stl")
    _mug().export(root / "mug.obj")
    trimesh.Scene(_parts()).export(root / "parts.glb")
    (root / "broken.stl").write_bytes(b"\x00 not a mesh " * 8)
    trimesh.creation.box([0.15, 0.15, 0.15]).export(root / "wide.ply")
    (root / "blob").mkdir()
    _blob().export(root / "blob" / "blob.obj")
    (root / "blob" / "blob.urdf").write_text(BLOB_URDF)
    (root / "objects.json").write_text(json.dumps({
        "mug": {"name": "test mug", "category": "containers", "asymmetric": True},
        "parts": {"mass_kg": GIVEN_MASS_KG, "friction": GIVEN_FRICTION},
    }))
    return root


def _snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {path.relative_to(root).as_posix(): (path.stat().st_size, path.stat().st_mtime_ns) for path in root.rglob("*")}


def _urdf_inertial(urdf_path: Path) -> tuple[float, np.ndarray, np.ndarray, float]:
    """(mass, com (3,), inertia (3, 3), lateral friction) as the URDF states them."""
    link = ElementTree.parse(urdf_path).getroot().find("link")
    inertia = link.find("inertial/inertia").attrib
    i = {name: float(value) for name, value in inertia.items()}
    tensor = np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]], [i["ixz"], i["iyz"], i["izz"]]])
    com = np.array([float(v) for v in link.find("inertial/origin").get("xyz").split()])
    friction = float(link.find("contact/lateral_friction").get("value"))
    return float(link.find("inertial/mass").get("value")), com, tensor, friction


def _metadata(spec) -> dict:
    return json.loads((spec.urdf_path.parent / "metadata.json").read_text())


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = _make_folder(tmp_path_factory.mktemp("meshes") / "objects")
    return root, _snapshot(root)


@pytest.fixture(scope="module")
def settings(tmp_path_factory):
    return MeshImportSettings(cache_dir=tmp_path_factory.mktemp("cache"), **QUICK)


@pytest.fixture(scope="module")
def imported(folder, settings):
    return load_object_set(folder[0], import_settings=settings)


def test_a_folder_of_meshes_becomes_a_set_and_the_broken_files_are_listed_with_their_reasons(folder, imported):
    root = folder[0]
    assert imported.source == f"mesh:{root.resolve()}"
    assert set(imported.ids) == {"box", "mug", "parts", "blob"}
    reasons = {path.relative_to(root).as_posix(): reason for path, reason in imported.skipped}
    assert set(reasons) == {"broken.stl", "wide.ply"}
    assert reasons["broken.stl"].startswith("unreadable")
    assert "wider than the open hand" in reasons["wide.ply"] and "0.150 m" in reasons["wide.ply"]
    assert len(imported.checksum()) == 64


def test_a_box_urdf_holds_its_volume_times_density_as_mass_with_the_box_inertia_and_centred_com(imported, settings):
    spec = imported.get("box")
    mass, com, inertia, friction = _urdf_inertial(spec.urdf_path)
    a, b, c = BOX_EXTENTS_M  # the box rests on its largest face, long side along x
    expected_mass = a * b * c * settings.density_kg_m3
    assert mass == pytest.approx(expected_mass, rel=1e-6) and spec.mass_kg == pytest.approx(expected_mass, rel=1e-6)
    assert np.allclose(inertia, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * expected_mass / 12.0, rtol=1e-5, atol=1e-12)
    assert np.allclose(com, [0.0, 0.0, c / 2.0], atol=1e-6)
    assert np.allclose(spec.extents_m, BOX_EXTENTS_M, atol=1e-6)
    assert friction == settings.friction
    # The visual mesh is the link frame's solid: trimesh's figures for it match the URDF's.
    visual = trimesh.load(spec.urdf_path.parent / "visual.obj", force="mesh")
    assert visual.is_watertight
    assert mass == pytest.approx(visual.volume * settings.density_kg_m3, rel=1e-5)
    assert np.allclose(inertia, visual.moment_inertia * settings.density_kg_m3, rtol=1e-4, atol=1e-12)
    assert np.allclose(com, visual.center_mass, atol=1e-6)


def test_a_concave_mugs_mass_principal_inertia_and_com_are_the_source_meshs_under_the_link_transform(imported, settings):
    spec = imported.get("mug")
    source = _mug()
    mass, com, urdf_inertia, _ = _urdf_inertial(spec.urdf_path)
    metadata = _metadata(spec)
    assert metadata["watertight"] and metadata["mass_properties_from"] == "mesh"
    assert mass == pytest.approx(source.volume * settings.density_kg_m3, rel=1e-5)
    inertia = np.array(metadata["inertia_kg_m2"])
    assert np.allclose(np.linalg.eigvalsh(inertia), np.linalg.eigvalsh(source.moment_inertia * settings.density_kg_m3), rtol=1e-4)
    visual = trimesh.load(spec.urdf_path.parent / "visual.obj", force="mesh")
    assert np.allclose(inertia, visual.moment_inertia * settings.density_kg_m3, rtol=1e-4, atol=1e-11)
    # The URDF holds the link-frame tensor's diagonal: PyBullet keeps the link's axes for its collision hulls.
    assert np.allclose(urdf_inertia, np.diag(np.diag(inertia)), rtol=1e-6, atol=0.0)
    source_to_link = np.array(metadata["source_to_link"])
    assert np.allclose(com, source_to_link[:3, :3] @ source.center_mass + source_to_link[:3, 3], atol=1e-6)
    assert metadata["decomposer"] == "vhacd" and metadata["collision_hulls"] >= 2
    hulls = (spec.urdf_path.parent / "collision.obj").read_text().count("\no ") + 1
    assert hulls == metadata["collision_hulls"]


def test_each_spec_carries_its_source_map_centre_of_mass_and_hull_figures_from_its_metadata(imported):
    for object_id in imported.ids:
        spec = imported.get(object_id)
        metadata, record = _metadata(spec), spec.import_record
        assert record.scale == metadata["scale"] == 1.0
        assert np.allclose(record.link_from_source, np.array(metadata["source_to_link"]), atol=1e-15)
        assert record.com_m == tuple(metadata["com_m"])
        assert (record.decomposer, record.collision_hulls) == (metadata["decomposer"], metadata["collision_hulls"])
        assert (record.hull_volume_ratio, record.hull_max_distance_m) == (metadata["hull_volume_ratio"], metadata["hull_max_distance_m"])
    # One call moves the mesh file's points into the link frame: the source mug lands on the visual mesh.
    mug = imported.get("mug")
    moved = trimesh.transform_points(_mug().vertices, mug.import_record.link_from_source)
    visual = trimesh.load(mug.urdf_path.parent / "visual.obj", force="mesh")
    assert np.allclose(moved.min(axis=0), visual.bounds[0], atol=1e-6) and np.allclose(moved.max(axis=0), visual.bounds[1], atol=1e-6)
    box = imported.get("box").import_record
    assert box.decomposer == "convex hull" and box.fidelity_ok and box.hull_volume_ratio == pytest.approx(1.0, abs=0.01)


def test_a_glb_scene_is_read_as_all_its_parts_and_a_given_mass_and_friction_are_written(imported):
    spec = imported.get("parts")
    parts_volume = sum(part.volume for part in _parts())
    mass, _, _, friction = _urdf_inertial(spec.urdf_path)
    metadata = _metadata(spec)
    assert metadata["volume_m3"] == pytest.approx(parts_volume, rel=1e-3)
    assert mass == pytest.approx(GIVEN_MASS_KG) and friction == pytest.approx(GIVEN_FRICTION)
    assert metadata["density_kg_m3"] == pytest.approx(GIVEN_MASS_KG / metadata["volume_m3"])
    assert np.allclose(np.linalg.eigvalsh(metadata["inertia_kg_m2"]), np.linalg.eigvalsh(trimesh.util.concatenate(_parts()).moment_inertia)
                       * metadata["density_kg_m3"], rtol=1e-3)


def test_a_urdfs_mesh_scale_is_used_its_unit_inertia_replaced_and_its_mesh_not_imported_twice(imported, settings):
    spec = imported.get("blob")
    scaled = _blob()
    scaled.apply_scale(BLOB_URDF_SCALE)
    mass, _, urdf_inertia, _ = _urdf_inertial(spec.urdf_path)
    assert mass == pytest.approx(scaled.volume * settings.density_kg_m3, rel=1e-3)
    inertia = np.array(_metadata(spec)["inertia_kg_m2"])
    assert np.allclose(np.linalg.eigvalsh(inertia), np.linalg.eigvalsh(scaled.moment_inertia * settings.density_kg_m3), rtol=1e-3)
    assert np.allclose(np.diag(urdf_inertia), np.diag(inertia)) and urdf_inertia.max() < 1e-3  # not the URDF's ixx = 1 kg m^2
    assert sorted(spec.extents_m) == pytest.approx(sorted(scaled.extents), abs=1e-4)
    assert "blob_obj" not in imported.ids and len([i for i in imported.ids if "blob" in i]) == 1
    color = ElementTree.parse(spec.urdf_path).getroot().find("link/visual/material/color").get("rgba")
    assert [float(v) for v in color.split()] == [0.1, 0.2, 0.9, 1.0]


def test_objects_json_names_categories_and_asymmetric_flags_reach_the_specs(imported):
    mug = imported.get("mug")
    assert (mug.name, mug.category, mug.asymmetric) == ("test mug", "containers", True)
    box = imported.get("box")
    assert (box.name, box.category, box.asymmetric) == ("box", "object", False)
    assert {spec.id for spec in imported.targets()} == set(imported.ids)


def test_resting_poses_start_with_the_link_frame_and_each_rests_its_aabb_bottom_centre_on_the_plane(imported, settings):
    for spec in (imported.get("mug"), imported.get("box"), imported.get("parts")):
        poses = spec.resting_poses
        assert 1 <= len(poses) <= settings.max_resting_poses
        assert np.allclose(np.array(poses[0].link_to_rest), np.eye(4), atol=1e-9)
        probabilities = [pose.probability for pose in poses]
        assert all(more >= less - 1e-9 for more, less in zip(probabilities, probabilities[1:]))  # ties may come in any order
        assert 0 < sum(probabilities) <= 1.0 + 1e-9
        vertices = trimesh.load(spec.urdf_path.parent / "visual.obj", force="mesh").vertices
        for pose in poses:
            transform = np.array(pose.link_to_rest)
            assert np.allclose(transform[:3, :3] @ transform[:3, :3].T, np.eye(3), atol=1e-9)
            placed = vertices @ transform[:3, :3].T + transform[:3, 3]
            lower, upper = placed.min(axis=0), placed.max(axis=0)
            assert np.allclose([(lower[0] + upper[0]) / 2, (lower[1] + upper[1]) / 2, lower[2]], 0.0, atol=1e-5)
    box_poses = imported.get("box").resting_poses
    assert len(box_poses) == 6  # a box rests on any of its faces
    # One pose for each way up: no two kept poses turn the same side of the object up.
    for spec in (imported.get("mug"), imported.get("parts")):
        ups = np.array([np.array(pose.link_to_rest)[2, :3] for pose in spec.resting_poses])
        cosines = ups @ ups.T - 2.0 * np.eye(len(ups))
        assert (cosines < np.cos(np.radians(settings.resting_pose_merge_deg))).all(), spec.id


def test_a_second_load_is_a_cache_hit_that_builds_and_writes_nothing(folder, imported, settings, monkeypatch):
    before = _snapshot(settings.cache_dir)

    def no_build(*args, **kwargs):
        raise AssertionError("a cached object was built again")

    monkeypatch.setattr(mesh_import, "_build", no_build)
    again = load_object_set(folder[0], import_settings=settings)
    assert [again.get(i) for i in again.ids] == [imported.get(i) for i in imported.ids]
    assert again.skipped == imported.skipped
    assert _snapshot(settings.cache_dir) == before


def test_nothing_is_written_into_the_imported_folder(folder, imported):
    root, before = folder
    assert _snapshot(root) == before
    assert all(not spec.urdf_path.resolve().is_relative_to(root.resolve()) for spec in (imported.get(i) for i in imported.ids))


def test_an_imported_concave_object_loads_in_the_scene_and_settles_on_the_table(imported):
    config = Config()
    with Scene(config) as scene:
        scene.reset(imported.get("mug"), trial=0)
        linear, angular = pybullet.getBaseVelocity(scene.target_id, physicsClientId=scene.client)
        assert np.linalg.norm(linear) < 0.01 and np.linalg.norm(angular) < 0.1
        lower, _ = pybullet.getAABB(scene.target_id, physicsClientId=scene.client)
        assert abs(lower[2] - config.scene.table_top_z_m) < 0.005
        position, quat = scene.object_link_pose(scene.target_id)
        assert abs(position[2] - config.scene.table_top_z_m) < 0.005  # the link frame is the resting pose's bottom centre
        up = np.array(pybullet.getMatrixFromQuaternion(quat)).reshape(3, 3)[:, 2]
        assert up[2] > 0.99  # it rests in the pose its link frame was made from


def test_a_mesh_that_stays_open_serves_with_its_convex_hulls_volume_and_a_small_hole_is_filled(tmp_path):
    root = tmp_path / "open"
    root.mkdir()
    tumbler = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=24)
    top = tumbler.face_normals[:, 2] > 0.99
    trimesh.Trimesh(tumbler.vertices, tumbler.faces[~top]).export(root / "tumbler.ply")
    box = trimesh.creation.box([0.04, 0.04, 0.04])
    lid = box.face_normals[:, 2] > 0.99
    trimesh.Trimesh(box.vertices, box.faces[~lid]).export(root / "holed_box.stl")  # a four-edge hole
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", **QUICK)
    imported = load_object_set(root, import_settings=settings)
    tumbler_metadata = _metadata(imported.get("tumbler"))
    assert not tumbler_metadata["watertight"] and tumbler_metadata["mass_properties_from"] == "convex hull"
    assert tumbler_metadata["volume_m3"] == pytest.approx(tumbler.convex_hull.volume, rel=1e-6)
    assert imported.get("tumbler").mass_kg == pytest.approx(tumbler.convex_hull.volume * settings.density_kg_m3, rel=1e-6)
    box_metadata = _metadata(imported.get("holed_box"))
    assert box_metadata["watertight"] and box_metadata["volume_m3"] == pytest.approx(0.04 ** 3, rel=1e-6)


def test_a_stray_triangle_hanging_off_a_closed_scan_is_dropped_so_the_mesh_is_its_solid(tmp_path):
    root = tmp_path / "scan"
    root.mkdir()
    scan = trimesh.creation.box(BOX_EXTENTS_M).subdivide().subdivide().subdivide().subdivide()  # 3,072 triangles
    a, b = scan.edges_unique[0]
    fin = len(scan.vertices)
    vertices = np.vstack([scan.vertices, (scan.vertices[a] + scan.vertices[b]) / 2 + [0.0, 0.0, 0.01]])
    trimesh.Trimesh(vertices, np.vstack([scan.faces, [[a, b, fin]]]), process=False).export(root / "scan.ply")
    metadata = _metadata(load_object_set(root, import_settings=MeshImportSettings(cache_dir=tmp_path / "cache", **QUICK)).get("scan"))
    assert metadata["watertight"] and metadata["volume_m3"] == pytest.approx(np.prod(BOX_EXTENTS_M), rel=1e-6)


def test_a_folder_with_nothing_usable_is_an_error_naming_it_and_each_reason(tmp_path):
    root = tmp_path / "unusable"
    root.mkdir()
    (root / "junk.obj").write_text("this is not a mesh\n")
    trimesh.creation.box([0.2, 0.2, 0.2]).export(root / "crate.stl")
    trimesh.Trimesh([[0, 0, 0], [0.05, 0, 0], [0, 0.05, 0], [0.05, 0.05, 0]], [[0, 1, 2], [1, 3, 2]]).export(root / "sheet.obj")
    with pytest.raises(ObjectSetError, match=r"unusable holds no usable object.*crate.stl: wider.*junk.obj: unreadable.*sheet.obj: no volume"):
        load_object_set(root, import_settings=MeshImportSettings(cache_dir=tmp_path / "cache", **QUICK))
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "objects.json").write_text(json.dumps({"mug": {"name": "a mug"}}))
    with pytest.raises(ObjectSetError, match="empty has an objects.json without urdf entries and no OBJ"):
        load_object_set(empty)


def test_objects_json_entries_for_absent_objects_or_with_unknown_keys_are_named(tmp_path):
    root = tmp_path / "typo"
    root.mkdir()
    trimesh.creation.box(BOX_EXTENTS_M).export(root / "box.stl")
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", **QUICK)
    (root / "objects.json").write_text(json.dumps({"bxo": {"name": "box"}}))
    with pytest.raises(ObjectSetError, match="'bxo' names no mesh or URDF in the folder.*found: box"):
        load_object_set(root, import_settings=settings)
    (root / "objects.json").write_text(json.dumps({"box": {"densty": 100}}))
    with pytest.raises(ObjectSetError, match="'box' has unknown key.*densty"):
        load_object_set(root, import_settings=settings)
    (root / "objects.json").write_text(json.dumps({"box": {"scale": -1}}))
    with pytest.raises(ObjectSetError, match="'box' scale must be a positive number"):
        load_object_set(root, import_settings=settings)


def test_an_objects_json_scale_is_the_objects_own_unit_and_the_cache_key_follows_it_but_not_names(tmp_path):
    root = tmp_path / "millimetres"
    root.mkdir()
    trimesh.creation.box([50.0, 30.0, 20.0]).export(root / "box.stl")
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", **QUICK)
    (root / "objects.json").write_text(json.dumps({"box": {"scale": 0.001}}))
    in_metres = load_object_set(root, import_settings=settings).get("box")
    assert np.allclose(in_metres.extents_m, BOX_EXTENTS_M, atol=1e-6)
    (root / "objects.json").write_text(json.dumps({"box": {"scale": 0.001, "name": "renamed"}}))
    # The record's map is rigid (poses on the mesh scaled to metres move with it); the metadata's takes the file's units.
    record, metadata = in_metres.import_record, _metadata(in_metres)
    assert record.scale == 0.001 and np.allclose(np.linalg.det(record.link_from_source[:3, :3]), 1.0)
    assert np.allclose(record.link_from_source @ np.diag([0.001] * 3 + [1.0]), metadata["source_to_link"])
    renamed = load_object_set(root, import_settings=settings).get("box")
    assert renamed.name == "renamed" and renamed.urdf_path == in_metres.urdf_path
    (root / "objects.json").write_text(json.dumps({"box": {"scale": 0.001, "density_kg_m3": 300.0}}))
    denser = load_object_set(root, import_settings=settings).get("box")
    assert denser.urdf_path != in_metres.urdf_path and denser.mass_kg == pytest.approx(2 * in_metres.mass_kg)


def test_the_cache_root_is_the_setting_else_the_environment_variable_else_the_home_cache(tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "env"))
    assert MeshImportSettings().cache_root() == tmp_path / "env" / "objects"
    assert MeshImportSettings(cache_dir=tmp_path / "arg").cache_root() == tmp_path / "arg" / "objects"
    monkeypatch.delenv(CACHE_DIR_ENV)
    assert MeshImportSettings().cache_root() == Path("~/.cache/sagp_batched/objects").expanduser()


def test_settings_refuse_values_that_cannot_make_an_object():
    with pytest.raises(ValueError, match="density_kg_m3 must be positive"):
        MeshImportSettings(density_kg_m3=0.0)
    with pytest.raises(ValueError, match="decomposer must be one of"):
        MeshImportSettings(decomposer="quickhull")
    with pytest.raises(ValueError, match="mass_kg must be positive"):
        MeshImportSettings(mass_kg=-1.0)


def _l_block(root: Path) -> Path:
    root.mkdir()
    bar = trimesh.creation.box([0.06, 0.02, 0.02])
    post = trimesh.creation.box([0.02, 0.02, 0.04])
    post.apply_translation([0.02, 0.0, 0.03])
    trimesh.util.concatenate([bar, post]).export(root / "l_block.obj")
    return root


def test_without_coacd_the_automatic_decomposer_is_vhacd(tmp_path, monkeypatch):
    monkeypatch.setattr(mesh_decompose, "_coacd_importable", lambda: False)
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", vhacd_resolution=20_000)
    spec = load_object_set(_l_block(tmp_path / "l"), import_settings=settings).get("l_block")
    assert _metadata(spec)["decomposer"] == "vhacd" and _metadata(spec)["collision_hulls"] >= 2
    with pytest.raises(ObjectSetError, match="decomposer 'coacd' is not installed"):
        load_object_set(tmp_path / "l", import_settings=MeshImportSettings(cache_dir=tmp_path / "cache", decomposer="coacd"))


def test_where_coacd_fails_the_automatic_choice_falls_back_to_vhacd_and_an_explicit_one_skips_the_object(tmp_path, monkeypatch):
    def failing(*args, **kwargs):
        raise RuntimeError("Wrong clip proposal!")

    monkeypatch.setattr(mesh_decompose, "coacd_hulls", failing)
    root = _l_block(tmp_path / "l")
    spec = load_object_set(root, import_settings=MeshImportSettings(cache_dir=tmp_path / "cache", vhacd_resolution=20_000)).get("l_block")
    metadata = _metadata(spec)
    assert metadata["decomposer"] == "vhacd" and spec.import_record.decomposer == "vhacd"
    assert "coacd" in metadata["decomposer_fallback_reason"] and "Wrong clip proposal" in metadata["decomposer_fallback_reason"]
    trimesh.creation.box(BOX_EXTENTS_M).export(root / "box.stl")
    explicit = load_object_set(root, import_settings=MeshImportSettings(cache_dir=tmp_path / "cache", decomposer="coacd"))
    assert explicit.ids == ("box",) and "collision decomposition (coacd) failed" in explicit.skipped[0][1]


def test_coacd_decomposes_a_concave_object_where_it_is_installed(tmp_path):
    pytest.importorskip("coacd")
    settings = MeshImportSettings(cache_dir=tmp_path / "cache", concavity_threshold=0.1, max_convex_hulls=4, coacd_resolution=500,
                                  coacd_mcts_iterations=10, coacd_mcts_nodes=5, coacd_mcts_max_depth=1)
    spec = load_object_set(_l_block(tmp_path / "l"), import_settings=settings).get("l_block")
    metadata = _metadata(spec)
    assert metadata["decomposer"] == "coacd" and 2 <= metadata["collision_hulls"] <= 4


def test_a_ycb_index_asymmetric_key_overrides_the_study_list(tmp_path):
    source = embedded_ycb_dir()
    index = json.loads((source / "objects.json").read_text())
    for object_id in ("025_mug", "005_tomato_soup_can"):
        shutil.copytree(source / object_id, tmp_path / object_id)
    (tmp_path / "objects.json").write_text(json.dumps({
        "025_mug": {**index["025_mug"], "asymmetric": False},
        "005_tomato_soup_can": {**index["005_tomato_soup_can"], "asymmetric": True},
    }))
    objects = load_object_set(tmp_path)
    assert objects.source.startswith("ycb:")
    assert not objects.get("025_mug").asymmetric and objects.get("005_tomato_soup_can").asymmetric
    (tmp_path / "objects.json").write_text(json.dumps({"025_mug": index["025_mug"]}))
    assert load_object_set(tmp_path).get("025_mug").asymmetric  # no key: the study's list decides

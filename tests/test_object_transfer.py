"""Objects reach workers by value: a packed set materialises under a worker's own folder as the driver's set."""
from __future__ import annotations

import concurrent.futures
import json
import pickle
import shutil
from pathlib import Path

import pytest
import trimesh

from sagp_batched.formats.frames import mesh_reference
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.object_transfer import (
    ObjectTransferError, materialise, materialised_dir, pack_objects, referenced_files, transfer_dir,
)
from sagp_batched.world.objects import embedded_ycb_dir, load_object_set

YCB_IDS = ["025_mug", "003_cracker_box", "061_foam_brick"]


def _same_specs(materialised, driver):
    assert materialised.ids == driver.ids and materialised.source == driver.source
    for object_id in driver.ids:
        here, there = materialised.get(object_id), driver.get(object_id)
        for field in ("id", "name", "category", "asymmetric", "mass_kg", "extents_m", "resting_poses"):
            assert getattr(here, field) == getattr(there, field), (object_id, field)


def _assert_files_travelled(materialised, driver, destination: Path):
    for object_id in driver.ids:
        sent, landed = referenced_files(driver.get(object_id)), referenced_files(materialised.get(object_id))
        assert len(sent) == len(landed) > 1
        for source, copy in zip(sent, landed):
            assert copy.is_relative_to(destination.resolve()), copy
            assert source.name == copy.name and source.read_bytes() == copy.read_bytes()


def test_the_embedded_ycb_set_travels_with_its_meshes_textures_and_checksum(tmp_path):
    driver = load_object_set(embedded_ycb_dir())
    packed = pickle.loads(pickle.dumps(pack_objects(driver, YCB_IDS)))  # what the object store hands a worker
    materialised = materialise(packed, tmp_path / "cache")
    destination = materialised_dir(packed, tmp_path / "cache")
    assert destination == transfer_dir(tmp_path / "cache") / packed.checksum
    assert materialised.checksum() == driver.subset(YCB_IDS).checksum() == packed.checksum
    _same_specs(materialised, driver.subset(YCB_IDS))
    _assert_files_travelled(materialised, driver.subset(YCB_IDS), destination)
    landed = {path.name for path in referenced_files(materialised.get("003_cracker_box"))}
    assert {"model.urdf", "textured.obj", "textured.mtl", "texture_map.jpg", "collision_coacd.obj"} <= landed
    assert not any(embedded_ycb_dir().resolve() in path.parents for path in referenced_files(materialised.get("025_mug")))
    # The grasp export names each mesh relative to the set's root, so a worker's file names it as the driver's does.
    for object_id in YCB_IDS:
        here, there = mesh_reference(materialised.get(object_id)), mesh_reference(driver.get(object_id))
        assert here[:3] == there[:3] and (here[3] == there[3]).all()


def test_the_set_packs_only_the_objects_asked_for(tmp_path):
    packed = pack_objects(load_object_set(), ["025_mug"])
    assert packed.ids == ("025_mug",)
    assert {name.split("/")[0] for name in packed.trees[0]} == {"025_mug", "objects.json"}


def _mesh_folder(root: Path) -> Path:
    root.mkdir(parents=True)
    trimesh.creation.box((0.05, 0.03, 0.02)).export(root / "box.stl")
    trimesh.creation.capsule(height=0.06, radius=0.02).export(root / "capsule.obj")
    (root / "objects.json").write_text(json.dumps({"capsule": {"name": "test capsule", "category": "cylinders"}}))
    return root


def test_an_imported_mesh_folder_travels_with_its_metadata_and_resting_poses(tmp_path):
    folder = _mesh_folder(tmp_path / "meshes")
    driver = load_object_set(folder, MeshImportSettings(cache_dir=tmp_path / "import_cache"))
    assert set(driver.ids) == {"box", "capsule"} and all(driver.get(i).resting_poses for i in driver.ids)
    packed = pack_objects(driver)
    materialised = materialise(packed, tmp_path / "worker_cache")
    destination = materialised_dir(packed, tmp_path / "worker_cache")
    assert materialised.checksum() == driver.checksum()
    _same_specs(materialised, driver)
    _assert_files_travelled(materialised, driver, destination)
    for object_id in driver.ids:
        metadata = Path(materialised.get(object_id).urdf_path).parent / "metadata.json"
        assert metadata.read_bytes() == (Path(driver.get(object_id).urdf_path).parent / "metadata.json").read_bytes()
        assert mesh_reference(materialised.get(object_id))[:3] == mesh_reference(driver.get(object_id))[:3]


def test_pybullet_data_objects_resolve_in_the_workers_own_pybullet_data(tmp_path):
    driver = load_object_set("pybullet_data").subset(["mug", "domino"])
    packed = pack_objects(driver)
    assert packed.trees == () and packed.nbytes == 0
    materialised = materialise(packed, tmp_path / "cache")
    assert materialised.checksum() == driver.checksum()
    _same_specs(materialised, driver)


def test_workers_of_one_node_share_one_materialised_folder_and_a_damaged_one_is_rewritten(tmp_path):
    packed = pack_objects(load_object_set(), ["025_mug"])
    with concurrent.futures.ThreadPoolExecutor(4) as pool:
        sets = list(pool.map(lambda _: materialise(packed, tmp_path / "cache"), range(4)))
    assert {str(s.get("025_mug").urdf_path) for s in sets} == {str(sets[0].get("025_mug").urdf_path)}
    assert [p.name for p in transfer_dir(tmp_path / "cache").iterdir()] == [packed.checksum], "no staging folder is left"
    mesh = Path(sets[0].get("025_mug").urdf_path).parent / "textured.obj"
    mesh.write_bytes(b"truncated")
    repaired = materialise(packed, tmp_path / "cache")
    assert mesh.read_bytes() == (load_object_set().get("025_mug").urdf_path.parent / "textured.obj").read_bytes()
    assert repaired.checksum() == packed.checksum


def test_a_set_that_does_not_materialise_as_the_drivers_is_refused(tmp_path):
    import dataclasses

    packed = pack_objects(load_object_set(), ["025_mug"])
    with pytest.raises(ObjectTransferError, match="not the driver's"):
        materialise(dataclasses.replace(packed, checksum="0" * 64), tmp_path / "cache")


def test_packing_an_object_whose_mesh_is_missing_names_the_file_in_one_line(tmp_path):
    copy = tmp_path / "ycb"
    shutil.copytree(embedded_ycb_dir(), copy)
    objects = load_object_set(copy)
    (copy / "025_mug" / "collision_coacd.obj").unlink()
    with pytest.raises(ObjectTransferError) as error:
        pack_objects(objects, ["025_mug"])
    message = str(error.value)
    assert "\n" not in message and "025_mug" in message and "collision_coacd.obj" in message and "does not exist" in message


def test_a_ray_study_whose_object_names_a_missing_texture_stops_in_one_line_before_ray_starts(tmp_path):
    from test_preflight import _batch

    copy = tmp_path / "ycb"
    shutil.copytree(embedded_ycb_dir(), copy)
    urdf = copy / "005_tomato_soup_can" / "model.urdf"
    # Loading checks meshes only; a texture the URDF names is first read when the objects are packed.
    urdf.write_text(urdf.read_text().replace("</material>", '<texture filename="label.png"/></material>', 1))
    done, out = _batch(tmp_path, copy, "--backend", "ray")
    errors = [line for line in done.stderr.splitlines() if line.startswith("error:")]
    assert done.returncode == 2 and len(errors) == 1 and "Traceback" not in done.stderr, done.stderr
    assert "005_tomato_soup_can" in errors[0] and "label.png" in errors[0] and "does not exist" in errors[0]
    assert not out.exists(), "nothing is written, and Ray is not started, for objects that cannot be packed"

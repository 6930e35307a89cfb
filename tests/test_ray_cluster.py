"""A real Ray cluster joined by address (on loopback): the study and the dataset runner give the local run's results."""
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

import sagp_batched.runtime as runtime
from sagp_batched.config import load_config
from sagp_batched.study.study_run import run_study
from sagp_batched.world.objects import CACHE_DIR_ENV, load_object_set
from test_study_e2e import _stable

# Ray rewrites 127.0.0.1 to the machine's outward address and turns on token authentication unless told
# not to; the head gets them in its environment, this process from conftest.
RAY_LOOPBACK_ENV = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_AUTH_MODE": "disabled"}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def worker_cache(tmp_path_factory):
    """The cache of the cluster's workers: apart from the driver's, as on a node of its own."""
    return tmp_path_factory.mktemp("worker_cache")


@pytest.fixture(scope="module")
def ray_cluster(worker_cache):
    pytest.importorskip("ray")
    assert all(os.environ.get(key) == value for key, value in RAY_LOOPBACK_ENV.items()), "conftest sets them before Ray is imported"
    port = _free_port()
    env = {**os.environ, **RAY_LOOPBACK_ENV, CACHE_DIR_ENV: str(worker_cache)}
    head = subprocess.Popen(
        [sys.executable, "-m", "ray.scripts.scripts", "start", "--head", "--node-ip-address", "127.0.0.1", "--port", str(port),
         "--num-cpus", "2", "--include-dashboard", "false", "--block"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )
    address = f"127.0.0.1:{port}"
    deadline = time.time() + 120
    while time.time() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            break
        except OSError:
            time.sleep(0.5)
    else:
        os.killpg(head.pid, signal.SIGKILL)
        pytest.fail("the Ray head did not start")
    yield address
    os.killpg(head.pid, signal.SIGTERM)
    try:
        head.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(head.pid, signal.SIGKILL)
        head.wait()


def _study(tmp_path, name, ycb_dir, **run):
    config = load_config("ci", overrides={"run": {"objects": ["005_tomato_soup_can"], "tasks": ["t1"], "methods": ["go"], "n_trials": 3,
                                                   "out": str(tmp_path / name), "objects_dir": str(ycb_dir), "export_grasps": True,
                                                   "save_frames": True, **run}})
    return run_study(config, load_object_set(config.run.objects_dir), config.run.methods, objects_dir=config.run.objects_dir, progress=False)


def _exported_files(out):
    return {path.relative_to(out).as_posix(): path.read_bytes() for folder in ("grasps", "frames") for path in sorted((out / folder).iterdir())}


def _moving_away_once_connected(driver_objects, moved_away):
    """A ``runtime.ray_session`` that moves the driver's objects folder away once Ray is connected, before
    any actor starts: the workers can get the objects from the object store only."""
    ray_session = runtime.ray_session

    @contextlib.contextmanager
    def session_then_move_the_folder(*args):
        with ray_session(*args):
            shutil.move(driver_objects, moved_away)
            yield

    return session_then_move_the_folder


@pytest.mark.slow
def test_a_study_on_a_cluster_joined_by_address_writes_the_local_records(tmp_path, ycb_dir, ray_cluster, worker_cache, monkeypatch):
    local = _study(tmp_path, "local", ycb_dir)
    # The driver's objects leave their folder once Ray is connected, before any actor starts: the workers can
    # get them from the object store only.
    driver_objects, moved_away = tmp_path / "driver_objects", tmp_path / "moved_away"
    shutil.copytree(ycb_dir, driver_objects)
    checksum = load_object_set(driver_objects).subset(["005_tomato_soup_can"]).checksum()
    session_then_move_the_folder = _moving_away_once_connected(driver_objects, moved_away)
    monkeypatch.setattr(runtime, "ray_session", session_then_move_the_folder)
    clustered = _study(tmp_path, "cluster", driver_objects, backend="ray", ray_address=ray_cluster, workers=2)
    assert not driver_objects.exists() and moved_away.is_dir()

    assert _stable(clustered.records) == _stable(local.records)
    assert len((tmp_path / "cluster" / "trials.jsonl").read_text().splitlines()) == 3, "the driver wrote every record"
    # Every exported file came back to the driver, the same as the local run's.
    local_files, cluster_files = _exported_files(tmp_path / "local"), _exported_files(tmp_path / "cluster")
    assert sum(name.startswith("grasps/") for name in local_files) == 3 and sum(name.startswith("frames/") for name in local_files) >= 6
    assert cluster_files.keys() == local_files.keys() and cluster_files == local_files
    # The workers read their objects from their own materialised folder, made from the object store.
    reports = [json.loads(line) for line in (tmp_path / "cluster" / "workers.jsonl").read_text().splitlines()]
    assert len(reports) == 3 and all(r["rss_bytes"] > 0 for r in reports)
    materialised = worker_cache / "transfer" / checksum
    assert {r["objects_dir"] for r in reports} == {str(materialised)}
    assert {r["pid"] for r in reports}.isdisjoint({os.getpid()})
    for path in (moved_away / "005_tomato_soup_can").iterdir():
        assert (materialised / "0" / "005_tomato_soup_can" / path.name).read_bytes() == path.read_bytes()


@pytest.mark.slow
def test_a_dataset_of_your_meshes_on_a_cluster_joined_by_address_writes_the_local_labels(tmp_path, ray_cluster, worker_cache, monkeypatch):
    import h5py
    import trimesh

    from runners import datagen

    meshes = tmp_path / "meshes"
    meshes.mkdir()
    trimesh.creation.box((0.05, 0.04, 0.08)).export(meshes / "box.stl")
    trimesh.creation.cylinder(0.03, 0.1, sections=24).export(meshes / "can.obj")
    driver_objects, moved_away = tmp_path / "driver_objects", tmp_path / "moved_away"
    shutil.copytree(meshes, driver_objects)
    session_then_move_the_folder = _moving_away_once_connected(driver_objects, moved_away)
    labels = {}
    common = ["--out", "--grasps-per-object", "8", "--captures", "1", "--pairs", "2000", "--no-progress"]
    runs = {"local": (meshes, ["--backend", "local"]),
            "cluster": (driver_objects, ["--backend", "ray", "--address", ray_cluster, "--workers", "2", "--grasps-per-chunk", "3"])}
    for name, (folder, backend) in runs.items():
        if name == "cluster":
            monkeypatch.setattr(runtime, "ray_session", session_then_move_the_folder)
        out = tmp_path / name
        assert datagen.main(["--objects-dir", str(folder), common[0], str(out), *common[1:], *backend]) == 0
        labels[name] = {}
        for entry in json.loads((out / "manifest.json").read_text())["objects"]:
            with h5py.File(out / entry["grasps"], "r") as f:
                flex = f["grasps/qualities/flex"]
                labels[name][entry["id"]] = {key: flex[key][()] for key in flex} | {"transforms": f["grasps/transforms"][()]}
    assert not driver_objects.exists() and moved_away.is_dir()
    assert labels["local"].keys() == labels["cluster"].keys() == {"box", "can"}
    for object_id, fields in labels["local"].items():
        assert len(fields["transforms"]) == 8
        for key, value in fields.items():
            assert np.array_equal(value, labels["cluster"][object_id][key], equal_nan=True), (object_id, key)
    # Every file is the driver's; the workers planned and simulated from the objects the object store brought.
    reports = [json.loads(line) for line in (tmp_path / "cluster" / "workers.jsonl").read_text().splitlines()]
    assert len(reports) == 2 + 6 and len({r["pid"] for r in reports}) == 2 and all(r["rss_bytes"] > 0 for r in reports)
    (materialised,) = {r["objects_dir"] for r in reports}
    assert materialised.startswith(str(worker_cache / "transfer"))

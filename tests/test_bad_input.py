"""Bad input to the study CLI is refused before any work: one ``error:`` line naming the setting, exit 2, nothing in --out.

Every case runs ``runners.batch.main`` in-process on a valid base command changed in one way; the control
test shows the base command itself reaches the study, so each refusal comes from the one change.
"""
import json
import shutil
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import pytest

import runners.batch
from sagp_batched.world.objects import embedded_ycb_dir

OBJECT_ID = "005_tomato_soup_can"
# A case's flag of this value is left out of the base command.
DROPPED = "<dropped>"


def _base_flags(tmp_path: Path) -> dict[str, str | None]:
    return {"--profile": "ci", "--objects": OBJECT_ID, "--tasks": "t1", "--n-trials": "1", "--methods": "go",
            "--objects-dir": str(embedded_ycb_dir()), "--out": str(tmp_path / "run"), "--no-progress": None}


def _argv(flags: dict[str, str | None]) -> list[str]:
    argv: list[str] = []
    for flag, value in flags.items():
        argv += [flag] if value is None else [flag, value]
    return argv


def _one_object_dir(tmp_path: Path) -> Path:
    """An objects directory holding one object of the embedded set, copied whole."""
    source = embedded_ycb_dir()
    objects_dir = tmp_path / "objects"
    shutil.copytree(source / OBJECT_ID, objects_dir / OBJECT_ID)
    entry = json.loads((source / "objects.json").read_text())[OBJECT_ID]
    (objects_dir / "objects.json").write_text(json.dumps({OBJECT_ID: entry}))
    return objects_dir


def _profile(text: str | bytes) -> Callable[[Path, pytest.MonkeyPatch], dict[str, str]]:
    def write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
        path = tmp_path / "profile.toml"
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        return {"--profile": str(path)}
    return write


def _broken_object(breakage: Callable[[Path], None]) -> Callable[[Path, pytest.MonkeyPatch], dict[str, str]]:
    def build(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
        objects_dir = _one_object_dir(tmp_path)
        breakage(objects_dir)
        return {"--objects-dir": str(objects_dir)}
    return build


def _single_object(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    return {"--objects-dir": str(_one_object_dir(tmp_path))}


def _no_display(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str | None]:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    return {"--gui": None}


def _ray_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    monkeypatch.setitem(sys.modules, "ray", None)  # makes ``import ray`` raise ImportError
    return {"--backend": "ray"}


@dataclass
class BadInput:
    claim: str
    flags: dict[str, str | None] = field(default_factory=dict)
    # Words the error line must hold: the setting (or flag, object, file) and the value refused.
    named: tuple[str, ...] = ()
    # Builds files in tmp_path or patches the process; returns further flags (None: a flag without a value).
    setup: Callable[[Path, pytest.MonkeyPatch], dict[str, str | None]] | None = None


def _mesh_gone(objects_dir: Path) -> None:
    (objects_dir / OBJECT_ID / "collision_coacd.obj").unlink()


def _urdf_gone(objects_dir: Path) -> None:
    (objects_dir / OBJECT_ID / "model.urdf").unlink()


def _urdf_not_xml(objects_dir: Path) -> None:
    (objects_dir / OBJECT_ID / "model.urdf").write_text("robot: not xml at all")


def _urdf_not_a_robot(objects_dir: Path) -> None:
    (objects_dir / OBJECT_ID / "model.urdf").write_text("<html><body/></html>")


def _index_not_utf8(objects_dir: Path) -> None:
    (objects_dir / "objects.json").write_bytes(b'{"\xff\xfe": {}}')


def _negative_mass(objects_dir: Path) -> None:
    index_path = objects_dir / "objects.json"
    index = json.loads(index_path.read_text())
    index[OBJECT_ID]["mass_kg"] = -1.0
    index_path.write_text(json.dumps(index))


CASES = [
    BadInput("negative --pairs is refused", {"--pairs": "-5"}, ("--pairs", "planner.n_pairs", "-5", "between 1 and")),
    BadInput("--pairs beyond the pair bound is refused", {"--pairs": "2000000000"}, ("--pairs", "planner.n_pairs", "2000000000")),
    BadInput("negative --trial-timeout is refused", {"--trial-timeout": "-1"}, ("--trial-timeout", "run.trial_timeout_s", "-1")),
    BadInput("nan --trial-timeout is refused", {"--trial-timeout": "nan"}, ("--trial-timeout", "run.trial_timeout_s", "finite", "nan")),
    BadInput("infinite --trial-timeout is refused", {"--trial-timeout": "inf"}, ("--trial-timeout", "finite", "inf")),
    BadInput("--n-trials beyond the trial bound is refused", {"--n-trials": "1000000000"}, ("--n-trials", "run.n_trials", "100,000")),
    BadInput("zero --n-trials is refused", {"--n-trials": "0"}, ("--n-trials", "run.n_trials", "0")),
    BadInput("zero --workers is refused", {"--workers": "0"}, ("--workers", "run.workers", "0")),
    BadInput("--workers beyond the worker bound is refused", {"--workers": "100000"}, ("--workers", "run.workers", "100000")),
    BadInput("an empty --objects is refused, not read as all", {"--objects": ""}, ("--objects", "run.objects", "empty")),
    BadInput("an empty --tasks is refused", {"--tasks": ""}, ("--tasks", "run.tasks", "empty")),
    BadInput("a --methods of only commas is refused", {"--methods": ","}, ("--methods", "run.methods", "empty")),
    BadInput("a task listed twice is refused", {"--tasks": "t1,t1"}, ("--tasks", "'t1'", "more than once")),
    BadInput("an unknown object id is refused", {"--objects": "999_no_such_thing"}, ("999_no_such_thing",)),
    BadInput("an unknown task is refused", {"--tasks": "t9"}, ("'t9'", "t1, t2, t3")),
    BadInput("an empty --out is refused", {"--out": ""}, ("--out", "run.out", "empty")),
    BadInput("a negative max_retries in a profile is refused", named=("rating.max_retries", "-1", ">= 0"),
             setup=_profile("[rating]\nmax_retries = -1\n")),
    BadInput("a nan in a profile is refused", named=("planner.min_width_m", "nan"), setup=_profile("[planner]\nmin_width_m = nan\n")),
    BadInput("a probability above 1 in a profile is refused", named=("planner.occupancy_max_fraction", "1.5", "between 0 and 1"),
             setup=_profile("[planner]\noccupancy_max_fraction = 1.5\n")),
    BadInput("zero execution attempts in a profile are refused", named=("execution.max_attempts", "0"),
             setup=_profile("[execution]\nmax_attempts = 0\n")),
    BadInput("a pair of the wrong length in a profile is refused", named=("scene.table_size_m", "2 entries"),
             setup=_profile("[scene]\ntable_size_m = [1.2]\n")),
    BadInput("a reversed range in a profile is refused", named=("scene.object_x_range_m", "low <= high"),
             setup=_profile("[scene]\nobject_x_range_m = [0.65, 0.45]\n")),
    BadInput("a word in a list of numbers in a profile is refused", named=("scene.table_size_m[1]", "'wide'"),
             setup=_profile('[scene]\ntable_size_m = [1.2, "wide"]\n')),
    BadInput("an unknown profile key is refused", named=("run.n_trails",), setup=_profile("[run]\nn_trails = 3\n")),
    BadInput("a value of the wrong type in a profile is refused", named=("planner.n_pairs", "'many'"),
             setup=_profile('[planner]\nn_pairs = "many"\n')),
    BadInput("a number for a path in a profile is refused", named=("run.objects_dir", "5"),
             setup=_profile("[run]\nobjects_dir = 5\n"), flags={"--objects-dir": DROPPED}),
    BadInput("an unknown run backend in a profile is refused", named=("run.backend", "'slurm'"),
             setup=_profile('[run]\nbackend = "slurm"\n')),
    BadInput("an unknown rating backend in a profile is refused", named=("rating.backend", "'gpt'"),
             setup=_profile('[rating]\nbackend = "gpt"\n')),
    BadInput("a profile whose methods all need a model, with the prior rater, is refused", {"--methods": DROPPED},
             ("run.methods", "model backend"), setup=_profile('[run]\nmethods = ["vd"]\n')),
    BadInput("a profile that is not UTF-8 is refused", named=("profile.toml", "UTF-8"),
             setup=_profile(b"[run]\nout = \"caf\xe9\"\n")),
    BadInput("an objects.json that is not UTF-8 is refused", named=("objects.json", "UTF-8"), setup=_broken_object(_index_not_utf8)),
    BadInput("a missing URDF is refused", named=(OBJECT_ID, "model.urdf", "does not exist"), setup=_broken_object(_urdf_gone)),
    BadInput("a URDF that is not XML is refused", named=(OBJECT_ID, "model.urdf", "not valid XML"),
             setup=_broken_object(_urdf_not_xml)),
    BadInput("an XML file that is not a URDF is refused", named=(OBJECT_ID, "<html>"), setup=_broken_object(_urdf_not_a_robot)),
    BadInput("a URDF whose mesh is missing is refused", named=(OBJECT_ID, "collision_coacd.obj", "does not exist"),
             setup=_broken_object(_mesh_gone)),
    BadInput("a negative object mass is refused", named=(OBJECT_ID, "mass_kg", "-1"), setup=_broken_object(_negative_mass)),
    BadInput("--gui without a display is refused", named=("--gui", "$DISPLAY"), setup=_no_display),
    BadInput("a refusal after a method is dropped for want of a model is still the only line",
             {"--profile": "paper", "--methods": DROPPED}, ("--gui",), setup=_no_display),
    BadInput("--backend ray without Ray is refused before anything is written", named=("--backend ray", "Ray"), setup=_ray_missing),
    BadInput("t3 on an object set without distractors is refused instead of repeating t1", {"--tasks": "t1,t3"},
             ("task t3 needs distractors",), setup=_single_object),
]


class ReachedTheStudy(Exception):
    pass


def _refuse_to_run(*args, **kwargs):
    raise ReachedTheStudy


@pytest.mark.parametrize("variant", ["as it is", "on one copied object", "with --objects all"])
def test_the_base_command_reaches_the_study(tmp_path, monkeypatch, variant):
    flags = _base_flags(tmp_path)
    if variant == "on one copied object":
        flags["--objects-dir"] = str(_one_object_dir(tmp_path))
    if variant == "with --objects all":
        flags["--objects"] = "all"
    monkeypatch.setattr(runners.batch, "run_study", _refuse_to_run)
    with pytest.raises(ReachedTheStudy):
        runners.batch.main(_argv(flags))


@pytest.mark.parametrize("case", CASES, ids=[case.claim for case in CASES])
def test_bad_input_is_refused_in_one_line_before_any_work(tmp_path, monkeypatch, capsys, case):
    flags = _base_flags(tmp_path)
    flags.update(case.setup(tmp_path, monkeypatch) if case.setup else {})
    for flag, value in case.flags.items():
        if value == DROPPED:
            flags.pop(flag)
        else:
            flags[flag] = value
    assert runners.batch.main(_argv(flags)) == 2
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    for word in case.named:
        assert word in lines[0], (word, lines[0])
    out = tmp_path / "run"
    assert not out.exists() or not any(out.iterdir())

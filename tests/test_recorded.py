"""Recorded values hold on other processors and still catch real changes: the comparison helper
(tests/recorded.py) passes what moves within a tolerance and names what moves beyond it, and the
recorded-value tests pass again under another float path, which the recording machine cannot show
on its own (another machine's attempt differed by 1.5e-11 from the recorded digits)."""
from __future__ import annotations

import json
import os
import platform
import re
import subprocess
import sys
from pathlib import Path

import pytest

from recorded import assert_close_to_recorded
from test_labelling import ATTEMPT_FIELDS, RECORDED_ATTEMPT_ATOL, RECORDED_ATTEMPT_RTOL, STUDY_ATTEMPTS

REPO = Path(__file__).resolve().parent.parent


def _assert_attempt(offset, summary, study):
    assert_close_to_recorded(summary, study, names=ATTEMPT_FIELDS, atol=RECORDED_ATTEMPT_ATOL, rtol=RECORDED_ATTEMPT_RTOL,
                             label=f"attempt {offset}")


def _moved(study: tuple, field: str, by: float) -> tuple:
    index = ATTEMPT_FIELDS.index(field)
    return (*study[:index], study[index] + by, *study[index + 1:])


def test_attempts_within_the_tolerance_of_the_recorded_ones_pass():
    for offset, study in STUDY_ATTEMPTS:
        _assert_attempt(offset, study, study)
        # Another processor's float path, and every float moved by most of its tolerance.
        _assert_attempt(offset, _moved(study, "orientation_change_deg", -1.5e-11), study)
        nudged = tuple(value + 0.9 * (RECORDED_ATTEMPT_ATOL + RECORDED_ATTEMPT_RTOL * abs(value)) if isinstance(value, float) else value
                       for value in study)
        _assert_attempt(offset, nudged, study)


def test_an_attempt_moved_beyond_the_tolerance_fails_naming_the_field_and_how_far_it_moved():
    offset, study = STUDY_ATTEMPTS[1]
    moved = _moved(study, "descent_tracking_error_rad", 3.2e-4)
    with pytest.raises(AssertionError) as failure:
        _assert_attempt(offset, moved, study)
    message = str(failure.value)
    assert message.startswith("attempt (0.05, 0.0): descent_tracking_error_rad moved by 3.2e-04 "), message
    assert f"(recorded {study[4]!r}, now {moved[4]!r}), tolerance 1.0e-06" in message
    assert len(message.splitlines()) == 1, "only the field that moved is named"
    # Just beyond the tolerance fails too; every field that moved is listed.
    just_beyond = _moved(_moved(study, "object_height_above_table_m", 2e-6), "lift_tracking_error_rad", -5e-6)
    with pytest.raises(AssertionError) as failure:
        _assert_attempt(offset, just_beyond, study)
    assert [line.split(" moved")[0] for line in str(failure.value).splitlines()] == [
        "attempt (0.05, 0.0): object_height_above_table_m", "attempt (0.05, 0.0): lift_tracking_error_rad",
    ]


def test_fields_that_are_not_floats_are_compared_exactly():
    offset, study = STUDY_ATTEMPTS[0]
    with pytest.raises(AssertionError, match=r"attempt \(0.0, 0.0\): failure_reason is now 'slipped', recorded None \(compared exactly\)"):
        _assert_attempt(offset, (study[0], "slipped", *study[2:]), study)
    with pytest.raises(AssertionError, match="success is now 1, recorded True"):
        _assert_attempt(offset, (1, *study[1:]), study)
    with pytest.raises(AssertionError, match="count is now 4, recorded 3"):
        assert_close_to_recorded({"count": 4}, {"count": 3}, atol=10.0)
    with pytest.raises(AssertionError, match="7 fields now, 6 recorded"):
        _assert_attempt(offset, study, study[:-1])


def test_mappings_nested_fields_and_tolerances_per_field():
    recorded = {"height_m": 0.25, "accelerations": (9.0, 30.0), "source": "planner"}
    assert_close_to_recorded({"height_m": 0.2500001, "accelerations": (9.0, 30.02), "source": "planner"}, recorded,
                             atol={"height_m": 1e-6, "accelerations": 0.05}, label="label")
    with pytest.raises(AssertionError, match=r"label: accelerations\[1\] moved by 2.0e-02 \(recorded 30.0, now 30.02\), tolerance 1.0e-02"):
        assert_close_to_recorded({"height_m": 0.25, "accelerations": (9.0, 30.02), "source": "planner"}, recorded,
                                 atol={"height_m": 1e-6, "accelerations": 0.01}, label="label")
    with pytest.raises(AssertionError, match=r"fields are now \['height_m'\]"):
        assert_close_to_recorded({"height_m": 0.25}, recorded, atol=1e-6)
    with pytest.raises(AssertionError, match="now nan, recorded 0.25"):
        assert_close_to_recorded([float("nan")], [0.25], atol=1.0, names=["height_m"])


# A few float paths the planner and the attempts take: the orientation change's quaternion dot
# products and norms and other BLAS calls through numpy (OpenBLAS picks kernels by processor), and
# torch's vectorised norms and MKL's acos, exp and GEMM (ATEN_CPU_CAPABILITY, MKL_CBWR).
FLOAT_PROBE = """
import hashlib, json
import numpy as np
import torch
rng = np.random.default_rng(0)
quats, vectors, matrices = rng.normal(size=(2000, 4)), rng.normal(size=(8, 1001)), rng.normal(size=(2, 96, 96))
angles = [abs(float(np.dot(a, b))) / (np.linalg.norm(a) * np.linalg.norm(b)) for a, b in zip(quats[0::2], quats[1::2])]
numpy_out = np.concatenate([angles, vectors @ vectors[0], (matrices[0] @ matrices[1]).ravel()])
generator = torch.Generator().manual_seed(0)
x, m = torch.rand(100_003, 3, generator=generator) * 2 - 1, torch.rand(2, 128, 128, generator=generator)
torch_out = torch.cat([x.norm(dim=1), torch.acos(x[:, 2]), torch.exp(x[:, 0]), (m[0] @ m[1]).ravel()])
print(json.dumps({"numpy": hashlib.sha256(numpy_out.tobytes()).hexdigest(), "torch": hashlib.sha256(torch_out.numpy().tobytes()).hexdigest()}))
"""


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    found = re.search(r"^flags\s*:(.*)$", text, re.MULTILINE)
    return set(found.group(1).split()) if found else set()


def _alternative_environments() -> list[dict[str, str]]:
    """Environments that send numpy's BLAS and torch's kernels down other float paths than this
    processor's own: an older OpenBLAS core (Haswell where the processor has AVX2 and FMA, else
    Prescott, which any x86-64 runs), torch's unvectorised kernels and MKL's compatible path."""
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return []
    cores = (["Haswell"] if {"avx2", "fma"} <= _cpu_flags() else []) + ["Prescott"]
    return [{"OPENBLAS_CORETYPE": core, "ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE"} for core in cores]


FLOAT_PATH_VARIABLES = ("OPENBLAS_CORETYPE", "ATEN_CPU_CAPABILITY", "MKL_CBWR")


def _environment(alternative: dict[str, str]) -> dict[str, str]:
    """This process's environment without any float-path choice of its own, plus ``alternative``'s."""
    return {**{key: value for key, value in os.environ.items() if key not in FLOAT_PATH_VARIABLES}, **alternative}


def _probe(alternative: dict[str, str]) -> dict[str, str]:
    done = subprocess.run([sys.executable, "-c", FLOAT_PROBE], env=_environment(alternative), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_the_recorded_value_tests_pass_under_another_processors_float_path():
    """The recorded-value tests (``-m recorded``) re-run with numpy's BLAS and torch's kernels on
    other float paths than this processor's own; on the machine that recorded the values
    OPENBLAS_CORETYPE=Haswell gives the other machine's attempt, 1.5e-11 from the recorded digits."""
    candidates = _alternative_environments()
    if not candidates:
        pytest.skip(f"no other OpenBLAS and torch float path is known for {platform.machine()}")
    native = _probe({})
    probed = [(env, _probe(env)) for env in candidates]
    changed = [env for env, floats in probed if floats["numpy"] != native["numpy"] and floats["torch"] != native["torch"]]
    assert changed, f"none of {candidates} changes both numpy's and torch's float output here: the re-run would show nothing"
    alternative = changed[0]
    done = subprocess.run(
        [sys.executable, "-m", "pytest", "-m", "recorded", "-p", "no:cacheprovider", "-q", "--no-header", str(REPO / "tests")],
        cwd=REPO, env=_environment(alternative), capture_output=True, text=True, timeout=600,
    )
    summary = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else ""
    assert done.returncode == 0, f"under {alternative}: {summary}\n{done.stdout[-6000:]}{done.stderr[-2000:]}"
    assert re.search(r"\b[1-9]\d* passed", summary) and "failed" not in summary, summary

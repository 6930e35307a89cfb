"""The one worker pool: units run here or in spawned processes come back with the same results, each
from a process that reports after it; a unit whose process dies gets the caller's result for it, or
stops the run with ``BrokenProcessPool``; an unknown backend is one error line."""
from __future__ import annotations

import atexit
import concurrent.futures
import os
from pathlib import Path

import pytest

from sagp_batched.config import ConfigError
from sagp_batched.workers import Recipe, WorkerPool


class _Squarer:
    """Squares its units; a negative one ends its process, as a crash in a simulator would."""

    objects_dir = "/objects/here"

    def __init__(self, offset: int = 0):
        self.offset = offset
        self.closed = False

    def run(self, unit: int) -> int:
        if unit < 0:
            os._exit(1)
        return unit * unit + self.offset

    def close(self) -> None:
        self.closed = True


def _pool(workers: int, **hooks) -> WorkerPool:
    return WorkerPool("local", workers, here=lambda: _Squarer(1), in_process=Recipe(_Squarer, (1,)), **hooks)


def test_units_run_here_or_in_processes_give_the_same_results_as_they_finish():
    with _pool(1) as pool:
        here = sorted((unit, result, report) for unit, result, report in pool.as_finished(range(5)))
    assert here == [(unit, unit * unit + 1, None) for unit in range(5)]
    with _pool(2) as pool:
        finished = list(pool.as_finished(range(5)))
    assert sorted((unit, result) for unit, result, _ in finished) == [(unit, result) for unit, result, _ in here]
    reports = [report for _, _, report in finished]
    assert os.getpid() not in {report.pid for report in reports} and all(r.objects_dir == "/objects/here" for r in reports)
    by_process: dict[int, list[int]] = {}
    for report in reports:
        by_process.setdefault(report.pid, []).append(report.units_done)
    assert all(sorted(counts) == list(range(1, len(counts) + 1)) for counts in by_process.values()), "each worker counts its own units"


def test_a_unit_whose_process_died_gets_the_callers_result_or_stops_the_run():
    with _pool(2, on_worker_death=lambda unit, exc: f"died: {type(exc).__name__}") as pool:
        results = {unit: result for unit, result, _ in pool.as_finished([-1])}
    assert results == {-1: "died: BrokenProcessPool"}
    with pytest.raises(concurrent.futures.process.BrokenProcessPool), _pool(2) as pool:
        list(pool.as_finished([-1]))


class _Printer:
    """Prints each unit without a newline (held in the process's output buffer); its making registers an
    exit handler that would leave ``marker`` behind if the interpreter tore itself down."""

    objects_dir = None

    def __init__(self, marker: str):
        atexit.register(Path(marker).write_text, "torn down")

    def run(self, unit: int) -> int:
        print(f"[unit {unit}]", end="")
        return unit

    def close(self) -> None:
        pass


def test_a_worker_process_ends_with_its_output_flushed_and_without_the_interpreters_teardown(tmp_path, capfd):
    marker = tmp_path / "teardown"
    with WorkerPool("local", 2, here=lambda: _Printer(str(marker)), in_process=Recipe(_Printer, (str(marker),))) as pool:
        assert sorted(result for _, result, _ in pool.as_finished(range(4))) == [0, 1, 2, 3]
    printed = capfd.readouterr().out
    assert all(f"[unit {unit}]" in printed for unit in range(4)), printed
    assert not marker.exists()


def test_an_unknown_backend_is_one_error_line():
    with pytest.raises(ConfigError, match="^unknown backend 'slurm' \\(known: local, ray\\)$"):
        WorkerPool("slurm", 2, here=_Squarer, in_process=Recipe(_Squarer), on_ray=Recipe(_Squarer))
    with pytest.raises(ConfigError, match="^unknown backend 'ray' \\(known: local\\)$"):
        WorkerPool("ray", 2, here=_Squarer, in_process=Recipe(_Squarer))

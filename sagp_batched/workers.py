"""One worker pool for every parallel run: the study's trial units, a dataset's object plans and chunks,
a relabel's chunks. The caller hands it units and says how a worker is made; it gets each unit's result
back as soon as that unit finishes, whichever worker ran it, and writes it before asking for the next.

Three ways to run, chosen by ``backend`` and ``workers``: here, in order (one local worker); spawned
processes (``local``, more than one: each a fresh interpreter with its own simulator, where fork would
copy the parent's torch thread pools and any open PyBullet client); Ray actors (``ray``: one actor per
worker holds its worker for the whole run, so a scene or a labeller is built once per worker, and each
actor is given one unit at a time, the rest waiting here in order). Ray is connected on the first unit,
to the cluster at ``ray_address`` or a local instance, and let go when the pool closes.

A worker away from here reports after every unit (``run_directory.WorkerReport``: process, node,
units done, resident memory, how long the unit took, where its objects were read). An interrupt or an
error in the caller closes the pool without starting anything further.
"""
from __future__ import annotations

import atexit
import collections
import concurrent.futures
import contextlib
import logging
import multiprocessing
import os
import socket
import sys
import time
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from .config import ConfigError
from .run_directory import WorkerReport
from . import runtime
from .runtime import configure_torch, ray_worker_stopped, resident_memory_bytes


class Worker(Protocol):
    """What a pool runs units on: ``run`` one unit; ``objects_dir``, where it read its objects (reported);
    ``close``, called on the worker that ran units here (one away from here ends with its process)."""

    objects_dir: str | None

    def run(self, unit: Any) -> Any: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class Recipe:
    """How a worker is made where it runs: ``make(*args)``. ``make`` is a module-level callable and
    ``args`` plain values: both travel to a spawned process or a Ray actor."""

    make: Callable[..., Worker]
    args: tuple = ()


class ReportingWorker:
    """A worker away from the driver (a spawned process, a Ray actor) and its count of finished units."""

    def __init__(self, recipe: Recipe):
        configure_torch()
        self.worker = recipe.make(*recipe.args)
        self.node = socket.gethostname()
        self.done = 0

    def run(self, unit: Any) -> tuple[Any, WorkerReport]:
        start = time.perf_counter()
        result = self.worker.run(unit)
        self.done += 1
        return result, WorkerReport(os.getpid(), self.node, self.done, resident_memory_bytes(), time.perf_counter() - start,
                                    self.worker.objects_dir)


_PROCESS_WORKER: ReportingWorker | None = None


def _host_in_process(recipe: Recipe) -> None:
    global _PROCESS_WORKER
    _PROCESS_WORKER = ReportingWorker(recipe)
    atexit.register(_end_without_teardown)


def _end_without_teardown() -> None:
    """A worker process's last step: its output flushed, it ends without the interpreter's teardown.

    A worker's simulators and tensors live in its own memory, which the system frees with the
    process, and every result has gone back through the pool before the pool lets it end. Tearing
    down torch, Open3D, PyBullet and MuJoCo module by module took ~0.6 s a process, which the
    driver waited for at the end of every parallel run. Registered after the worker is made, so it
    runs after the exit handlers of what the units import later and before those of what the worker
    imported to start (a pool worker ends with status 0 either way)."""
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)


def _run_in_process(unit: Any) -> tuple[Any, WorkerReport]:
    return _PROCESS_WORKER.run(unit)


Finished = tuple[Any, Any, "WorkerReport | None"]  # (unit, result, the worker's report; None for a unit run here)


class _InThisProcess:
    """One worker, made on the first unit, running units in the order submitted."""

    def __init__(self, make: Callable[[], Worker]):
        self.make, self.worker = make, None
        self.queue: collections.deque = collections.deque()

    def submit(self, unit: Any) -> None:
        self.queue.append(unit)

    def __len__(self) -> int:
        return len(self.queue)

    def next_done(self) -> Finished:
        if self.worker is None:
            self.worker = self.make()
        unit = self.queue.popleft()
        return unit, self.worker.run(unit), None

    def close(self, finished: bool) -> None:
        if self.worker is not None:
            self.worker.close()


class _SpawnedProcesses:
    """Each worker a spawned process, made by its pool's initializer and kept for the whole run."""

    def __init__(self, recipe: Recipe, workers: int, on_worker_death: Callable[[Any, BaseException], Any] | None):
        self.pool = concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                                           initializer=_host_in_process, initargs=(recipe,))
        self.on_worker_death = on_worker_death
        self.running: dict[concurrent.futures.Future, Any] = {}

    def submit(self, unit: Any) -> None:
        self.running[self.pool.submit(_run_in_process, unit)] = unit

    def __len__(self) -> int:
        return len(self.running)

    def next_done(self) -> Finished:
        done, _ = concurrent.futures.wait(self.running, return_when=concurrent.futures.FIRST_COMPLETED)
        future = next(iter(done))
        unit = self.running.pop(future)
        try:
            result, report = future.result()
        except concurrent.futures.process.BrokenProcessPool as exc:
            if self.on_worker_death is None:
                raise
            return unit, self.on_worker_death(unit, exc), None
        return unit, result, report

    def close(self, finished: bool) -> None:
        self.pool.shutdown(wait=finished, cancel_futures=True)


class _RayActors:
    """Each worker a Ray actor, given one unit at a time, the rest waiting here in order."""

    def __init__(self, recipe: Recipe, workers: int, ray_address: str | None):
        self.session = contextlib.ExitStack()
        # Looked up when the pool starts, so a test can stand in for the session.
        self.session.enter_context(runtime.ray_session(ray_address, workers))
        import ray

        self.ray = ray
        # The recipe (the objects among its arguments) is put once: each node that runs an actor fetches it.
        recipe_ref = ray.put(recipe)
        actor = ray.remote(num_cpus=1)(ReportingWorker)
        self.idle = [actor.remote(recipe_ref) for _ in range(workers)]
        self.waiting: collections.deque = collections.deque()
        self.running: dict = {}

    def submit(self, unit: Any) -> None:
        self.waiting.append(unit)
        self._dispatch()

    def _dispatch(self) -> None:
        while self.idle and self.waiting:
            unit, worker = self.waiting.popleft(), self.idle.pop()
            self.running[worker.run.remote(unit)] = (unit, worker)

    def __len__(self) -> int:
        return len(self.running) + len(self.waiting)

    def next_done(self) -> Finished:
        [ref], _ = self.ray.wait(list(self.running), num_returns=1)
        unit, worker = self.running.pop(ref)
        self.idle.append(worker)
        try:
            result, report = self.ray.get(ref)
        except self.ray.exceptions.RayActorError as exc:
            raise ray_worker_stopped(exc) from exc
        self._dispatch()
        return unit, result, report

    def close(self, finished: bool) -> None:
        for ref in self.running:
            self.ray.cancel(ref)
        self.session.close()


class WorkerPool:
    """Units run on ``workers`` workers by ``backend`` ("local" or "ray"), results as they finish.

    ``here``: makes the worker a single local worker runs units on, in this process; ``in_process``
    and ``on_ray``: the recipes of a spawned process's and a Ray actor's worker. ``on_worker_death``
    gives the result of a unit whose process died (``BrokenProcessPool``); without it the error
    propagates. Nothing starts before the first unit. Use as a context manager."""

    def __init__(self, backend: str, workers: int, *, here: Callable[[], Worker], in_process: Recipe, on_ray: Recipe | None = None,
                 ray_address: str | None = None, on_worker_death: Callable[[Any, BaseException], Any] | None = None):
        if backend not in ("local", "ray") or (backend == "ray" and on_ray is None):
            raise ConfigError(f"unknown backend '{backend}' (known: local{', ray' if on_ray is not None else ''})")
        self._start: Callable[[], Any]
        if backend == "ray":
            self._start = lambda: _RayActors(on_ray, workers, ray_address)
        elif workers > 1:
            self._start = lambda: _SpawnedProcesses(in_process, workers, on_worker_death)
        else:
            self._start = lambda: _InThisProcess(here)
        self._runner: Any = None

    def submit(self, unit: Any) -> None:
        if self._runner is None:
            self._runner = self._start()
        self._runner.submit(unit)

    def __len__(self) -> int:
        return 0 if self._runner is None else len(self._runner)

    def next_done(self) -> Finished:
        """The next unit to finish, its result and its worker's report."""
        return self._runner.next_done()

    def as_finished(self, units: Any) -> Any:
        """Every one of ``units`` submitted, then each (unit, result, report) as it finishes."""
        for unit in units:
            self.submit(unit)
        while len(self):
            yield self.next_done()

    def __enter__(self) -> "WorkerPool":
        return self

    def __exit__(self, exc_type: Any, *exc_info: Any) -> None:
        if self._runner is not None:
            # After an interrupt or a failed write nothing further starts and nothing running is waited for.
            self._runner.close(finished=exc_type is None)

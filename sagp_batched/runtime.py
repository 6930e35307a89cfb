"""Process-wide runtime settings, set once by entry points (runners, workers), never at import."""
from __future__ import annotations

import contextlib
import os
from typing import Iterator

import torch

# With 2 intra-op threads torch can stall in small-tensor loops on 2-vCPU machines; with 1 it
# does not. The planner's tensors are small (<= 1e6 elements), so one thread costs little and
# parallelism comes from worker processes instead.
DEFAULT_TORCH_THREADS = 1


def configure_torch(threads: int = DEFAULT_TORCH_THREADS) -> None:
    torch.set_num_threads(threads)


def resident_memory_bytes() -> int:
    """This process's resident set size: ``psutil`` where it is installed, else ``/proc/self/statm`` (Linux)."""
    try:
        import psutil
    except ImportError:
        with open("/proc/self/statm") as statm:
            return int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    return int(psutil.Process().memory_info().rss)


def ray_worker_stopped(exc: BaseException) -> Exception:
    """The one-line error of a Ray actor that could not start or stopped mid-run (its objects could not
    be written, its node went away): Ray puts the worker's own exception on the last line of its text."""
    from .config import ConfigError

    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return ConfigError(f"a Ray worker stopped: {lines[-1] if lines else exc}")


@contextlib.contextmanager
def ray_session(address: str | None, workers: int) -> Iterator[None]:
    """Ray connected for the block: to the cluster at ``address``, else a local instance of
    ``workers`` CPUs; one started here is shut down after, one already running is left as it was."""
    from .config import ConfigError

    try:
        import ray
    except ImportError as exc:
        raise ConfigError("--backend ray needs Ray: pip install 'sagp-batched[ray]'") from exc
    started_here = not ray.is_initialized()
    if started_here:
        if address:
            ray.init(address=address, log_to_driver=False)
        else:
            # "local" starts a fresh instance even where another cluster on this machine left its address behind.
            ray.init(address="local", num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        if started_here:
            ray.shutdown()

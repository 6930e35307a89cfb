"""A run directory: one run's settings, the lock that keeps it to one process, and its trials file.

Guarantees: every line of ``trials.jsonl`` is a whole, valid record or is moved out of it; a directory
holds the records of one run's settings and object set only; one process writes it at a time.

- Each record is written as one line and synced before the next; a write that fails (a full disk)
  is cut back to the last whole line and stops the run with ``TrialWriteError``.
- On resume, a last line without its newline (a run killed while writing it) and every line that is
  not a record (``records.record_problem``) move to ``trials.rejected.jsonl`` with the reason, and
  their trials run again.
- ``RunLock`` holds an exclusive lock on ``.lock`` for the whole run; a second process is refused.
"""
from __future__ import annotations

import contextlib
import dataclasses
import errno
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from .config import Config, ConfigError
from .records import record_key, record_problem

TRIALS_FILE = "trials.jsonl"
# One line per unit a worker process finished: its pid, node, units run so far, resident memory.
WORKERS_FILE = "workers.jsonl"
REJECTED_FILE = "trials.rejected.jsonl"
LOCK_FILE = ".lock"
CONFIG_FILE = "config.json"
PROVENANCE_FILE = "provenance.json"
# Settings that say how a run is executed or which of its trials to run, not what a record holds:
# they may differ on resume.
EXECUTION_ONLY = {"out", "workers", "backend", "ray_address", "gui", "trial_timeout_s", "objects", "tasks", "methods",
                  "n_trials", "save_frames", "export_grasps", "keep_errors"}
# A rejected line is kept whole up to this size; beyond it only its head, so a huge line cannot fill the disk twice.
REJECTED_LINE_MAX_CHARS = 100_000


class RunDirectoryError(ConfigError):
    """The run directory cannot take this run; the message is one line."""


class RunDirectoryMismatch(RunDirectoryError):
    """The run directory holds a run made with other settings or another object set."""


class RunDirectoryBusy(RunDirectoryError):
    """Another process is running into the same directory."""


class TrialWriteError(RunDirectoryError):
    """A record could not be written whole (a full disk, a read-only file system)."""


def _os_reason(exc: OSError) -> str:
    return exc.strerror or errno.errorcode.get(exc.errno or 0, str(exc))


@dataclass
class RejectedLine:
    line_number: int  # 1-based, in the file as it was found
    reason: str
    text: str


@dataclass
class TrialsFile:
    """The valid records of a trials file (the last one per key) and the lines it rejected."""

    records: list[dict[str, Any]]
    rejected: list[RejectedLine] = field(default_factory=list)


def _split_lines(data: bytes) -> Iterator[tuple[int, bytes, bool]]:
    """(line number, bytes, ends with a newline) for each non-blank line."""
    lines = data.split(b"\n")
    for number, raw in enumerate(lines, start=1):
        whole = number < len(lines)
        if raw.strip():
            yield number, raw, whole


def _parse_line(raw: bytes, whole: bool) -> tuple[dict[str, Any] | None, str | None]:
    if not whole:
        return None, "torn line: no end of line (a run stopped while writing it)"
    try:
        text = raw.decode("utf-8")
        record = json.loads(text)
    except UnicodeDecodeError:
        return None, "not UTF-8"
    except (ValueError, RecursionError) as exc:
        return None, f"not JSON ({type(exc).__name__})"
    problem = record_problem(record)
    return (None, f"not a trial record: {problem}") if problem else (record, None)


def scan_trials_file(path: Path) -> TrialsFile:
    """Read ``path`` without changing it: its valid records (last one per key) and its rejected lines."""
    if not path.exists():
        return TrialsFile([])
    by_key: dict[tuple, dict[str, Any]] = {}
    rejected = []
    for number, raw, whole in _split_lines(path.read_bytes()):
        record, reason = _parse_line(raw, whole)
        if record is None:
            rejected.append(RejectedLine(number, reason, raw[:REJECTED_LINE_MAX_CHARS].decode("utf-8", "replace")))
        else:
            by_key[record_key(record)] = record
    return TrialsFile(list(by_key.values()), rejected)


def read_records(path: Path) -> list[dict[str, Any]]:
    """The valid records of a trials file, the last one per (object, task, method, trial)."""
    return scan_trials_file(path).records


def _fsync_directory(directory: Path) -> None:
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def recover_trials_file(path: Path) -> TrialsFile:
    """Move every line of ``path`` that is not a whole record to ``trials.rejected.jsonl`` (with its
    reason) and rewrite ``path`` with the rest, atomically; return what was kept and rejected."""
    scanned = scan_trials_file(path)
    if not scanned.rejected:
        return scanned
    try:
        with (path.parent / REJECTED_FILE).open("a", encoding="utf-8") as rejected_file:
            for line in scanned.rejected:
                rejected_file.write(json.dumps({"line": line.line_number, "reason": line.reason, "text": line.text}) + "\n")
            rejected_file.flush()
            os.fsync(rejected_file.fileno())
        kept = path.with_suffix(".jsonl.tmp")
        rejected_lines = {line.line_number for line in scanned.rejected}
        with kept.open("wb") as kept_file:
            for number, raw, _ in _split_lines(path.read_bytes()):
                if number not in rejected_lines:
                    kept_file.write(raw + b"\n")
            kept_file.flush()
            os.fsync(kept_file.fileno())
        os.replace(kept, path)
        _fsync_directory(path.parent)
    except OSError as exc:
        raise TrialWriteError(f"cannot set aside the rejected lines of {path}: {_os_reason(exc)}") from exc
    return scanned


class TrialWriter:
    """Appends records to a trials file, one whole line each, synced before the next."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self._file = path.open("ab")
        except OSError as exc:
            raise TrialWriteError(f"cannot open {path}: {_os_reason(exc)}") from exc

    def write(self, record: dict[str, Any]) -> None:
        problem = record_problem(record)
        if problem:  # a record the next resume would reject must never be written
            raise ValueError(f"refusing to write an invalid trial record: {problem}")
        line = (json.dumps(record, sort_keys=True) + "\n").encode("utf-8")
        whole_size = self._file.tell()
        try:
            self._file.write(line)
            self._file.flush()
            os.fsync(self._file.fileno())
        except OSError as exc:
            self._cut_back(whole_size)
            raise TrialWriteError(
                f"cannot write {self.path}: {_os_reason(exc)}; every finished trial before it is kept: "
                "free space and run the same command again to resume"
            ) from exc

    def _cut_back(self, size: int) -> None:
        """Drop whatever part of a failed line reached the file, so no torn line is left."""
        with contextlib.suppress(OSError):  # the unwritten buffer is what failed: the truncation below discards it
            self._file.close()
        with open(self.path, "r+b") as file:
            file.truncate(size)
            with contextlib.suppress(OSError):  # the truncation stands in the page cache even if this sync fails
                os.fsync(file.fileno())
        self._file = self.path.open("ab")

    def close(self) -> None:
        with contextlib.suppress(OSError):  # every record was synced when written: nothing is pending
            self._file.close()


class RunLock:
    """An exclusive lock on the run directory for as long as a run writes it (``fcntl.flock``: the
    kernel drops it when the process ends, so a killed run leaves no stale lock)."""

    def __init__(self, out_dir: Path):
        self.path = out_dir / LOCK_FILE
        self._file = None

    def __enter__(self) -> "RunLock":
        import fcntl

        try:
            self._file = self.path.open("a+", encoding="utf-8")
        except OSError as exc:
            raise RunDirectoryError(f"cannot lock {self.path.parent}: {_os_reason(exc)}") from exc
        try:
            fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.seek(0)
            holder = self._file.read().strip() or "unknown"
            self._file.close()
            raise RunDirectoryBusy(
                f"{self.path.parent} is in use by another run (pid {holder}); wait for it to finish or choose another --out"
            ) from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(str(os.getpid()))
        self._file.flush()
        return self

    def __exit__(self, *exc_info: Any) -> None:
        import fcntl

        fcntl.flock(self._file.fileno(), fcntl.LOCK_UN)
        self._file.close()


def _record_settings(config_dict: dict[str, Any]) -> dict[str, Any]:
    settings = dict(config_dict)
    settings["run"] = {k: v for k, v in config_dict.get("run", {}).items() if k not in EXECUTION_ONLY}
    return settings


def _read_json(path: Path) -> dict[str, Any]:
    try:
        value = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise RunDirectoryError(f"{path} is unreadable ({type(exc).__name__}); choose another --out or delete that directory") from exc
    if not isinstance(value, dict):
        raise RunDirectoryError(f"{path} is not a JSON object; choose another --out or delete that directory")
    return value


def check_same_run(out_dir: Path, config: Config, objects_checksum: str, objects_source: str) -> None:
    """Refuse to resume into ``out_dir`` with settings or an object set that would change its records."""
    saved = out_dir / CONFIG_FILE
    if not saved.exists():
        return
    previous = _record_settings(_read_json(saved))
    current = _record_settings(json.loads(json.dumps(config.to_dict())))
    differing = sorted(
        f"{section}.{key}"
        for section in sorted(set(previous) | set(current))
        for key in sorted(set(previous.get(section, {})) | set(current.get(section, {})))
        if previous.get(section, {}).get(key) != current.get(section, {}).get(key)
    )
    if differing:
        raise RunDirectoryMismatch(
            f"{out_dir} holds a run made with other settings ({', '.join(differing)}); choose another --out or delete that directory"
        )
    provenance_path = out_dir / PROVENANCE_FILE
    if provenance_path.exists():
        objects = _read_json(provenance_path).get("objects") or {}
        if objects.get("checksum") != objects_checksum:
            raise RunDirectoryMismatch(
                f"{out_dir} holds a run made with another object set ({objects.get('source')}, now {objects_source}); "
                "choose another --out or delete that directory"
            )


def path_inside(base: Path, name: str) -> Path:
    """``base / name`` for a relative ``name`` that stays inside ``base``; ``ValueError`` for one that would leave it."""
    relative = Path(name)
    if relative.is_absolute() or ".." in relative.parts or not relative.parts:
        raise ValueError(f"{name!r} is not a path inside {base}")
    return base / relative


def run_file_path(out_dir: Path, name: str) -> Path:
    """The path of a worker's file ``name`` (run-relative) in the run directory; one that would leave it is refused."""
    try:
        return path_inside(out_dir, name)
    except ValueError as exc:
        raise RunDirectoryError(f"refusing to write a file: {exc}") from None


def write_file_atomically(path: Path, contents: bytes) -> None:
    """Write ``path`` whole and synced (a temporary file beside it, then a rename): a reader finds the old
    file or the new one, never part of one. Raises ``RunDirectoryError`` (one line) if the disk refuses."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with temporary.open("wb") as file:
            file.write(contents)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise RunDirectoryError(f"cannot write {path}: {_os_reason(exc)}") from exc


def write_json(path: Path, value: Any) -> None:
    """Write a run file whole (temporary file, then rename), as one ``RunDirectoryError`` line if the disk refuses."""
    temporary = path.with_name(path.name + ".tmp")
    try:
        temporary.write_text(json.dumps(value, indent=2, sort_keys=True, default=str), encoding="utf-8")
        os.replace(temporary, path)
    except OSError as exc:
        temporary.unlink(missing_ok=True)
        raise RunDirectoryError(f"cannot write {path}: {_os_reason(exc)}") from exc


@dataclass(frozen=True)
class WorkerReport:
    """A worker process just after finishing a unit of work (a study's trial unit; a dataset's object
    plan or chunk of grasps): which process on which node, how many units it has run, its resident
    memory, how long the unit took, and the folder its objects were read from."""

    pid: int
    node: str
    units_done: int
    rss_bytes: int
    unit_s: float
    objects_dir: str | None

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def append_json_line(path: Path, value: dict[str, Any]) -> None:
    """One JSON line appended to ``path`` (a run's ``workers.jsonl``); ``RunDirectoryError`` if it cannot be written."""
    try:
        with path.open("a", encoding="utf-8") as file:
            file.write(json.dumps(value, sort_keys=True) + "\n")
    except OSError as exc:
        raise RunDirectoryError(f"cannot write {path}: {exc.strerror or exc}") from exc

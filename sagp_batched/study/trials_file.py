"""A study's trials file, ``trials.jsonl``: one trial record per line (``records.TrialRecord.to_json``).

Guarantees: every line of ``trials.jsonl`` is a whole, valid record or is moved out of it.

- Each record is written as one line and synced before the next; a write that fails (a full disk)
  is cut back to the last whole line and stops the run with ``TrialWriteError``.
- On resume, a last line without its newline (a run killed while writing it) and every line that is
  not a record (``records.record_problem``) move to ``trials.rejected.jsonl`` with the reason, and
  their trials run again.
"""
from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

from ..run_directory import RunDirectoryError, os_reason
from .records import record_key, record_problem

TRIALS_FILE = "trials.jsonl"
REJECTED_FILE = "trials.rejected.jsonl"
# A rejected line is kept whole up to this size; beyond it only its head, so a huge line cannot fill the disk twice.
REJECTED_LINE_MAX_CHARS = 100_000


class TrialWriteError(RunDirectoryError):
    """A record could not be written whole (a full disk, a read-only file system)."""


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
        raise TrialWriteError(f"cannot set aside the rejected lines of {path}: {os_reason(exc)}") from exc
    return scanned


class TrialWriter:
    """Appends records to a trials file, one whole line each, synced before the next."""

    def __init__(self, path: Path):
        self.path = path
        try:
            self._file = path.open("ab")
        except OSError as exc:
            raise TrialWriteError(f"cannot open {path}: {os_reason(exc)}") from exc

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
                f"cannot write {self.path}: {os_reason(exc)}; every finished trial before it is kept: "
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

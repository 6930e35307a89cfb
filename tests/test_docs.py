"""The README and the documentation site against the code: the site builds with warnings as errors, every
Python example of the pages runs, every command line they show names a runner and flags it accepts, and
the record tables list the schema's fields."""
from __future__ import annotations

import importlib
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from sagp_batched.attempt import ATTEMPT_RECORD_FIELDS
from sagp_batched.study.records import OPTIONAL_RECORD_FIELDS, RECORD_FIELDS

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = sorted(DOCS.rglob("*.md")) + [REPO / "README.md"]
FENCE = re.compile(r"^```(\w*)\n(.*?)^```", flags=re.MULTILINE | re.DOTALL)
RUNNER_CALL = re.compile(r"python -m runners\.(\w+)")
README_MAX_LINES = 200


def _blocks(page: Path, language: str) -> list[str]:
    return [body for lang, body in FENCE.findall(page.read_text(encoding="utf-8")) if lang == language]


def _runner_calls(block: str) -> list[tuple[str, list[str]]]:
    """Each ``python -m runners.NAME ...`` of a shell block: the runner and the flags given to it."""
    calls = []
    for line in block.replace("\\\n", " ").splitlines():
        line = line.split(" #", 1)[0]
        for match in RUNNER_CALL.finditer(line):
            rest = re.split(r"&&|\||;", line[match.end():], maxsplit=1)[0]
            calls.append((match.group(1), [token.split("=", 1)[0] for token in shlex.split(rest) if token.startswith("--")]))
    return calls


def test_the_readme_is_a_short_page():
    assert len((REPO / "README.md").read_text(encoding="utf-8").splitlines()) <= README_MAX_LINES


def test_the_site_builds_with_warnings_as_errors(tmp_path):
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-4000:]
    assert (tmp_path / "site" / "reference" / "planning" / "index.html").read_text(encoding="utf-8").count("plan_batch") > 0


def test_every_page_is_in_the_site_s_navigation():
    nav = (REPO / "mkdocs.yml").read_text(encoding="utf-8")
    listed = set(re.findall(r":\s*([\w/.-]+\.md)\s*$", nav, flags=re.MULTILINE))
    assert listed == {str(page.relative_to(DOCS)) for page in DOCS.rglob("*.md")}


@pytest.mark.parametrize("page", [page for page in PAGES if _blocks(page, "python")], ids=lambda page: page.name)
def test_a_page_s_python_examples_run(page, tmp_path):
    # Run outside the checkout, as a user's script would, the page's blocks in order as one program.
    script = tmp_path / "example.py"
    script.write_text("\n".join(_blocks(page, "python")), encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]


def test_every_command_line_on_a_page_names_a_runner_and_flags_it_takes():
    checked = 0
    for page in PAGES:
        for block in _blocks(page, "bash"):
            for runner, flags in _runner_calls(block):
                module = importlib.import_module(f"runners.{runner}")
                known = {option for action in module.build_parser()._actions for option in action.option_strings}
                unknown = sorted(set(flags) - known)
                assert not unknown, f"{page.name}: runners.{runner} takes no {', '.join(unknown)}"
                checked += 1
    assert checked >= 10


def test_the_command_check_catches_a_flag_a_runner_does_not_take():
    (call,) = _runner_calls("python -m runners.batch --n-trials 2 --no-such-flag 3 && echo done  # --ignored\n")
    assert call == ("batch", ["--n-trials", "--no-such-flag"])
    known = {option for action in importlib.import_module("runners.batch").build_parser()._actions for option in action.option_strings}
    assert "--no-such-flag" not in known and "--n-trials" in known


def _table_keys(page: Path, header: str) -> tuple[str, ...]:
    table = page.read_text(encoding="utf-8").split(header, 1)[1].split("\n\n", 1)[0]
    return tuple(re.findall(r"^\| `(\w+)` \|", table, flags=re.MULTILINE))


def test_the_records_page_lists_exactly_the_record_and_attempt_fields():
    page = DOCS / "formats" / "records.md"
    assert _table_keys(page, "| record field | type | meaning |") == tuple(RECORD_FIELDS) + tuple(OPTIONAL_RECORD_FIELDS)
    assert _table_keys(page, "| attempt field | unit | meaning |") == ATTEMPT_RECORD_FIELDS

"""make test runs the tests marked ``alone`` after the rest, in a run of their own that reads only the files
naming the mark (the Makefile's ALONE_FILES: collecting the whole suite again to find its few tests took ~10 s
of a busy machine). A test marked alone in a file that does not name it would never run there."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.conftest import ALONE_FILES

TESTS = Path(__file__).resolve().parent
NAMES_THE_MARK = re.compile(r"mark\.alone")  # the Makefile's grep -E 'mark\.alone'


def test_every_test_marked_alone_is_in_a_file_make_test_reads_for_them(request: pytest.FixtureRequest) -> None:
    read = {path for path in TESTS.rglob("*.py") if NAMES_THE_MARK.search(path.read_text(encoding="utf-8"))}
    marked = request.config.stash.get(ALONE_FILES, set())
    assert marked <= read, f"marked alone, not read by make test's alone run: {sorted(map(str, marked - read))}"

"""The fenced code blocks of the docs a newcomer copies from, and which test runs each as written.

Every block of README.md and docs/clients.md is either run by a test named in ``RUN_BY`` or marked in
the markdown, on the line before its fence, with ``<!-- not run: why -->`` (what only the rig, the
package index or the suite itself can run). ``tests/test_docs_snippets.py`` checks that the two lists
cover every block, so a block added to either page without a test fails the suite.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FENCE = re.compile(r"^(?:<!-- not run: (?P<why>.+?) -->\n)?```(?P<lang>\w*)\n(?P<code>.*?)^```", re.S | re.M)
PAGES = ("README.md", "docs/clients.md")


@dataclass(frozen=True)
class Block:
    page: str  # relative to the checkout
    lang: str
    code: str
    line: int  # of the opening fence, 1-based
    not_run: str | None  # the marker's reason, None for a block a test runs

    @property
    def first_line(self) -> str:
        return self.code.splitlines()[0] if self.code else ""


def blocks(page: str) -> list[Block]:
    text = (ROOT / page).read_text(encoding="utf-8")
    found = []
    for match in FENCE.finditer(text):
        fence = match.start("lang") - 3
        found.append(Block(page, match.group("lang"), match.group("code"), text.count("\n", 0, fence) + 1,
                           match.group("why")))
    return found


def block(page: str, first_line: str, lang: str | None = None) -> Block:
    """The block of ``page`` whose first line starts with ``first_line`` (of language ``lang`` if given)."""
    matches = [b for b in blocks(page) if b.first_line.startswith(first_line) and lang in (None, b.lang)]
    assert len(matches) == 1, f"{page}: {len(matches)} blocks start with {first_line!r}"
    return matches[0]


# (page, the block's first line, or its start): the test that runs it as written
RUN_BY = {
    ("README.md", "TOKEN=$(cat ~/.local/state/graytrack/token)"):
        "tests/client/test_readme_examples.py::test_the_readmes_rest_and_websocket_block_works_as_written",
    ("README.md", "[daemon]"):
        "tests/client/test_readme_examples.py::test_the_readmes_realtime_block_turns_sched_fifo_off",
    ("docs/clients.md", "from itertools import islice"):
        "tests/client/test_docs_examples.py::test_the_python_example_runs_with_the_client_installed_alone",
    ("docs/clients.md", ".venv/bin/graytrack epics"):
        "tests/client/test_docs_examples.py::test_the_epics_block_reads_and_writes_through_the_venvs_caproto",
    ("docs/clients.md", "from bluesky import RunEngine"):
        "tests/client/test_docs_examples.py::test_the_bluesky_example_counts_and_scans_fresh_frames",
    ("docs/clients.md", ".venv/bin/pip install pipython"):
        "tests/client/test_docs_examples.py::test_the_pi_block_drives_the_simulated_controller_with_pipython",
}

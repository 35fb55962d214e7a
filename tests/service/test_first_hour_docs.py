"""What a newcomer copies from the README and the docs runs in their shell as written (issue 39, item 8):
extras quoted (zsh globs unquoted brackets: "no matches found"), the command reached where `make run`
installed it, the stream read without a tool the checkout does not install."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit
ROOT = Path(__file__).resolve().parents[2]
TEXTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "graytrack").rglob("*.py")),
         *sorted((ROOT / "service").rglob("*.py"))]
PIP_EXTRA = re.compile(r"pip install (-e )?(?P<target>\S*\[[^\]]*\]\S*)")


def test_every_pip_install_of_an_extra_is_quoted_for_zsh() -> None:
    unquoted = [f"{path.relative_to(ROOT)}: {m.group(0)}" for path in TEXTS
                for m in PIP_EXTRA.finditer(path.read_text()) if m.group("target")[0] not in "'\""]
    assert unquoted == []


def test_the_readme_reaches_the_command_where_make_run_installed_it_and_reads_the_stream_without_websocat() -> None:
    readme = (ROOT / "README.md").read_text()
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert "graytrack" in scripts  # what `.venv/bin/graytrack` is
    assert "`.venv/bin/graytrack demo`" in readme and ". .venv/bin/activate" in readme
    heading = next(line for line in readme.splitlines() if line.startswith("## Command line"))
    assert ".venv/bin/graytrack" in heading
    stream = next(line for line in readme.splitlines() if "ws://localhost:8000/ws/position" in line)
    assert stream.startswith(".venv/bin/python -m websockets ") and "websocat" not in stream.split("#")[0]
    extras = [line for line in readme.splitlines() if "'graytrack[epics]'" in line]
    assert extras and all(".venv/bin/pip install -e '.[epics]'" in line for line in extras)  # a checkout's venv

"""Examples in the docs that run on any machine, run here exactly as written (the ones that need the
rig's own camera, network or serial port are for the rig: docs/bring-up.md says what each shows)."""

from __future__ import annotations

import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit
DOCS = Path(__file__).resolve().parent.parent / "docs"
SVG = "{http://www.w3.org/2000/svg}"


def sh_block(doc: Path, first_line: str) -> str:
    for found in re.finditer(r"^```sh\n(.*?)^```", doc.read_text(encoding="utf-8"), re.S | re.M):
        if found.group(1).startswith(first_line):
            return found.group(1)
    raise AssertionError(f"{doc.name}: no sh block starting {first_line!r}")


def test_the_bring_up_target_generator_writes_a_sine_print_of_whole_periods(tmp_path: Path) -> None:
    code = sh_block(DOCS / "bring-up.md", "python3 - <<'EOF'")
    subprocess.run(["bash", "-c", code], cwd=tmp_path, check=True, capture_output=True, timeout=60)
    svg = ET.parse(tmp_path / "target.svg").getroot()
    period, length, steps = (float(v) for v in re.search(
        r"period, length, height, steps = ([\d.]+), ([\d.]+), [\d.]+, (\d+)", code).groups())
    width_mm = float(svg.get("width").removesuffix("mm"))
    periods = width_mm / period
    assert periods == pytest.approx(round(periods), abs=1e-6) and width_mm <= length, "whole periods on the sheet"
    gray = [int(stop.get("stop-color")[1:3], 16) for stop in svg.iter(f"{SVG}stop")]
    assert len(gray) == round(periods) * steps + 1
    assert (min(gray), max(gray)) == (28, 228), "mid-gray ± 100"
    assert gray[0] == gray[int(steps)] == 128, "a period a cycle"


def test_the_readmes_realtime_block_is_a_configuration_that_changes_only_the_priority(tmp_path: Path) -> None:
    """README's "Real-time priority": the default it states is the daemon's, and its block, saved as
    the config file, is a configuration the daemon accepts with every thread at normal scheduling."""
    from graytrack.drivers.realtime import DEFAULT_LEVEL
    from graytrack.service.daemon.settings import Settings, load_settings
    from tests.doc_blocks import block

    readme = (DOCS.parent / "README.md").read_text(encoding="utf-8")
    assert f"`[daemon] realtime_priority = {DEFAULT_LEVEL}`" in readme and DEFAULT_LEVEL > 0
    assert Settings().daemon.realtime_priority == DEFAULT_LEVEL
    config = tmp_path / "graytrack.toml"
    config.write_text(block("README.md", "[daemon]", "toml").code)
    settings = load_settings(config)
    assert settings.daemon.realtime_priority == 0
    assert settings.model_dump(exclude={"daemon"}) == Settings().model_dump(exclude={"daemon"}), "nothing else changes"


def test_every_block_of_the_readme_and_the_clients_page_is_run_by_a_test_or_marked_as_not_run() -> None:
    import ast

    from tests.doc_blocks import PAGES, ROOT, RUN_BY, blocks

    claimed: dict[tuple[str, str], list[int]] = {key: [] for key in RUN_BY}
    unclaimed, marked = [], []
    for page in PAGES:
        for found in blocks(page):
            keys = [key for key in RUN_BY if key[0] == page and found.first_line.startswith(key[1])]
            if found.not_run is not None:
                assert not keys, f"{page}:{found.line} is marked not run but {RUN_BY[keys[0]]} runs it"
                marked.append(f"{page}:{found.line}")
            elif keys:
                for key in keys:
                    claimed[key].append(found.line)
            else:
                unclaimed.append(f"{page}:{found.line} ({found.first_line!r})")
    assert unclaimed == [], "blocks no test runs and not marked <!-- not run: why -->"
    assert {key: lines for key, lines in claimed.items() if len(lines) != 1} == {}, "each key names one block"
    assert len(marked) <= 2, marked  # the install lines and `make test`: few
    for test in RUN_BY.values():  # the test named exists
        path, name = test.split("::")
        functions = {node.name for node in ast.walk(ast.parse((ROOT / path).read_text()))
                     if isinstance(node, ast.FunctionDef)}
        assert name in functions, test

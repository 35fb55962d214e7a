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

"""docs/clients.md's Python and bluesky examples, run as written against the daemon `make run` starts.

The code blocks are read from the markdown; the one change is the port (the daemon here listens on
a free one, not on 8000), and the test asserts the block names ``http://127.0.0.1:8000`` so that
change is all. The Python example runs in the venv where the client was installed alone (no numpy),
the bluesky one in this venv (ophyd-async and bluesky installed). They fail on the doc as it was:
``data_dir="/var/lib/graytrack"`` has no token file, and the bluesky example printed nothing.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from tests.client.conftest import ROOT, MakeRun, Venv

DOC = ROOT / "docs" / "clients.md"
MAKE_RUN_URL = "http://127.0.0.1:8000"
RUN_S = 300.0  # the first example may follow the daemon's own calibration (~20 s here, minutes on a slow host)
TRACKS_MM = 0.01  # a frame against the target it was taken at (the virtual rig tracks to a few µm)


def example(heading: str) -> str:
    """The first ```python block under the ``## `` heading that starts with ``heading``."""
    section = re.search(rf"^## {re.escape(heading)}.*?(?=^## )", DOC.read_text(encoding="utf-8"), re.S | re.M)
    assert section, f"{DOC.name}: no section {heading!r}"
    block = re.search(r"^```python\n(.*?)^```", section.group(0), re.S | re.M)
    assert block, f"{DOC.name}, {heading!r}: no python block"
    return block.group(1)


def run(python: Path | str, code: str, daemon: MakeRun) -> list[str]:
    assert MAKE_RUN_URL in code, "the example talks to make run's daemon"
    done = subprocess.run([str(python), "-c", code.replace(MAKE_RUN_URL, daemon.url)], cwd=daemon.home,
                          env=daemon.env(), capture_output=True, text=True, timeout=RUN_S)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.splitlines()


def test_the_python_example_runs_with_the_client_installed_alone(make_run: MakeRun, client_venv: Venv) -> None:
    lines = run(client_venv.python, example("Python"), make_run)
    progress = [line for line in lines if re.fullmatch(r"\d+% .+", line)]
    frames = [line.split() for line in lines if line not in progress]
    assert len(frames) == 10, lines  # "seq x_mm locked", ten of them (a gap line would be counted here too)
    seqs = [int(seq) for seq, _, _ in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == 10
    assert all(locked == "True" and abs(float(x) - 5.0) < TRACKS_MM for _, x, locked in frames), frames
    if progress:  # it followed a calibration (the daemon's own at its first start) to the end
        assert progress[-1].startswith("100% "), progress


def test_the_bluesky_example_counts_and_scans_fresh_frames(make_run: MakeRun) -> None:
    lines = run(sys.executable, example("bluesky"), make_run)
    events = [re.fullmatch(r"(\d+) (-?[\d.]+) mm ± ([\d.]+) µm ?(-?[\d.]*)", line) for line in lines]
    assert all(events) and len(events) == 8, lines  # count: 5 events, scan: 3
    count, scan = events[:5], events[5:]
    assert [int(e.group(1)) for e in count] == [1, 2, 3, 4, 5] and all(e.group(4) == "" for e in count)
    assert [int(e.group(1)) for e in scan] == [1, 2, 3]
    for event, target in zip(scan, (2.0, 3.0, 4.0)):
        assert abs(float(event.group(4)) - target) < 1e-6, "the stage's readback at the setpoint"
        assert abs(float(event.group(2)) - target) < TRACKS_MM, "the encoder sees the stage there"
    assert all(0 < float(e.group(3)) < 10 for e in events), "the bound, in µm"

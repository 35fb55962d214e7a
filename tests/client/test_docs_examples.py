"""docs/clients.md's blocks, run as written against the daemon `make run` starts.

The code blocks are read from the markdown; the one change is the port (the daemon here listens on
a free one, not on 8000), and the test asserts the block names ``http://127.0.0.1:8000`` so that
change is all. The Python example runs in the venv where the client was installed alone (no numpy),
the bluesky one in this venv (ophyd-async and bluesky installed). They fail on the doc as it was:
``data_dir="/var/lib/graytrack"`` has no token file, and the bluesky example printed nothing. The
shell blocks (EPICS, PI) run in bash from the checkout, whose ``.venv`` they call: this venv, where
`make install` put caproto and PIPython. The EPICS block failed as it was (``caget: command not
found``, and the caproto client it suggested was the system python's) and left caproto's repeater
running; the PI block used a port it never made.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import httpx

from tests.client.conftest import ROOT, MakeRun, Venv
from tests.doc_blocks import block
from tests.service.helpers import wait_for
from tests.service.test_epics import ca_ports

DOC = ROOT / "docs" / "clients.md"
MAKE_RUN_URL = "http://127.0.0.1:8000"
RUN_S = 300.0  # the first example may follow the daemon's own calibration (~20 s here, minutes on a slow host)
TRACKS_MM = 0.01  # a frame against the target it was taken at (the virtual rig tracks to a few µm)
SHELL_S = 120.0  # a shell block: a bridge or a controller started, a few calls, stopped
PI_LINK = "/tmp/ttyPI"  # the PI block's link; the test puts it in a folder of its own (runs in parallel)


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


def tracking(daemon: MakeRun) -> None:
    """Until the daemon tracks (its first start calibrates; the stage refuses moves meanwhile)."""
    wait_for(lambda: httpx.get(f"{daemon.url}/api/status", timeout=5).json()["state"] == "tracking",
             RUN_S, "the daemon to track")


def repeaters() -> set[int]:
    """Pids of caproto repeaters running on this machine (the EPICS block must leave none behind)."""
    found = set()
    for entry in Path("/proc").iterdir():
        try:
            if entry.name.isdigit() and b"caproto" in (cmdline := (entry / "cmdline").read_bytes()) \
                    and b"repeater" in cmdline:
                found.add(int(entry.name))
        except OSError:  # ended meanwhile
            pass
    return found


def shell(code: str, env: dict[str, str]) -> list[str]:
    """``code`` in bash from the checkout, as a user pastes it there; its printed lines."""
    done = subprocess.run(["bash", "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=SHELL_S)
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-3000:])
    return done.stdout.splitlines()


def test_the_epics_block_reads_and_writes_through_the_venvs_caproto(make_run: MakeRun) -> None:
    code = block("docs/clients.md", ".venv/bin/graytrack epics").code
    assert MAKE_RUN_URL in code and "caget" not in code.replace("`caget`", "")
    tracking(make_run)
    before = repeaters()
    with ca_ports():  # Channel Access on loopback, on ports of its own (the environment a lab would set)
        lines = shell(code.replace(MAKE_RUN_URL, make_run.url), make_run.env())
    read = {name: value.strip("[]") for name, value in (line.split(maxsplit=1) for line in lines[:3])}
    assert list(read) == ["LAB:GT1:STATE", "LAB:GT1:X_MM", "LAB:GT1:LOCKED"], lines
    assert read["LAB:GT1:STATE"] in {"tracking", "unreachable"}, read  # the bridge's first poll may be pending
    assert 0.0 <= float(read["LAB:GT1:X_MM"]) <= 10.46, read  # within the stroke
    assert read["LAB:GT1:LOCKED"] in {"Locked", "Unlocked"}, read
    assert [line.split()[:3] for line in lines[3:]] == [["Old", ":", "LAB:GT1:TARGET_MM"],
                                                        ["New", ":", "LAB:GT1:TARGET_MM"]], lines
    assert float(lines[-1].split()[-1].strip("[]")) == 5.0, lines  # the daemon's target_mm read back
    status = httpx.get(f"{make_run.url}/api/status", timeout=5).json()
    assert status["target_mm"] == 5.0, status  # the put moved the stage
    assert repeaters() <= before, "a caproto repeater was left running"


def test_the_pi_block_drives_the_simulated_controller_with_pipython(tmp_path: Path) -> None:
    code = block("docs/clients.md", ".venv/bin/pip install pipython").code
    link = tmp_path / "ttyPI"
    assert code.count(PI_LINK) >= 3  # made, waited for, opened
    lines = shell(code.replace(PI_LINK, str(link)), dict(os.environ))
    assert "OrderedDict([('1', 5.0)])" in lines, "\n".join(lines)  # PIPython's qPOS: the axis at its target
    assert lines[-1] == f"stopped by SIGTERM; {link} removed", lines
    assert not link.exists() and not link.is_symlink(), "the controller stopped and took its link"

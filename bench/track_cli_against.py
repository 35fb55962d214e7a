"""`graytrack track` on every model of ``bench/track_speed.py models``, on this checkout and on another
revision, in turns: frames/s of each side by side, with the ratio this tree / REF.

``track_speed_against.py`` compares the ``plain`` part; the models part builds a model and a run for
every effect family and scenario (minutes of calibration), which both revisions should read the same:
here they are built once, by this tree, saved (model, the seed paper's model fitted on the same
calibration, the run), and each revision's ``graytrack track`` (in a child process, its editable
install pointed at that revision's files) times the same files, ``ROUNDS`` alternating runs, best of
``REPEATS`` CPU-timed calls each (time.process_time: on a shared machine the wall clock also counts
the neighbours' turns; read the ratios).

Run: .venv/bin/python bench/track_cli_against.py [REF=main] [ROUNDS=2] [SUBSTRING of a model's label]
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
REPEATS = 3
# the child: graytrack.* resolved in ROOT, then `graytrack track` timed on each case folder of CASES
CHILD = """
import contextlib, io, os, sys, time
import __editable___graytrack_0_1_0_finder as finder
for key, value in list(finder.MAPPING.items()):
    finder.MAPPING[key] = value.replace({here!r}, {root!r}, 1)
from graytrack.service.cli import main as cli

def job(folder, which):
    argv = ["track", os.path.join(folder, "run.npz"), "--model", os.path.join(folder, which + ".json"),
            "--out", os.path.join(folder, which + ".csv")]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        cli(argv)

for case in sorted(os.listdir({cases!r})):
    folder = os.path.join({cases!r}, case)
    for which in ("plain", "model"):
        job(folder, which)  # imports and compilations before the clock
        best = float("inf")
        for _ in range({repeats}):
            start = time.process_time()
            job(folder, which)
            best = min(best, time.process_time() - start)
        print(case, which, {frames} / best, flush=True)
"""


def build(cases: str, selection: str) -> dict[str, tuple[str, int]]:
    """Every model of the bench (``selection``: a substring of its label) saved under ``cases``:
    {folder name: (label, rows)}; the frames of every run (the same for all)."""
    sys.path.insert(0, os.path.join(HERE, "bench"))
    import track_speed

    from graytrack.core.models.io import save_model
    from graytrack.core.recording import save

    labels = {}
    for i, (label, model, plain, run) in enumerate(track_speed.every_model(selection)):
        folder = os.path.join(cases, f"{i:02d}")
        os.makedirs(folder)
        save_model(model, os.path.join(folder, "model.json"))
        save_model(plain, os.path.join(folder, "plain.json"))
        save(run, os.path.join(folder, "run.npz"))
        labels[f"{i:02d}"] = (label, 1 if run.frames.ndim == 2 else run.frames.shape[1])
    return labels


def frames_per_s(root: str, cases: str) -> dict[tuple[str, str], float]:
    code = CHILD.format(here=HERE, root=root, cases=cases, repeats=REPEATS, frames=_frames(cases))
    out = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True).stdout
    return {(case, which): float(value) for case, which, value in (line.split() for line in out.splitlines())}


def _frames(cases: str) -> int:
    import numpy as np

    with np.load(os.path.join(cases, sorted(os.listdir(cases))[0], "run.npz")) as run:
        return int(run["frames"].shape[0])


def main() -> None:
    ref = sys.argv[1] if len(sys.argv) > 1 else "main"
    rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    selection = sys.argv[3] if len(sys.argv) > 3 else ""
    with tempfile.TemporaryDirectory() as root, tempfile.TemporaryDirectory() as cases:
        archive = subprocess.run(["git", "archive", ref], cwd=HERE, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", root], input=archive, check=True)
        labels = build(cases, selection)
        best: dict[str, dict[tuple[str, str], float]] = {"ref": {}, "this": {}}
        for _ in range(rounds):
            for name, tree in (("ref", root), ("this", HERE)):
                for key, value in frames_per_s(tree, cases).items():
                    best[name][key] = max(best[name].get(key, 0.0), value)
    print(f"graytrack track frames/s, best of {rounds} alternating runs ({REPEATS} calls each): "
          f"{ref} against this tree")
    print(f"{'model':70} {'rows':>4} {'plain ' + ref:>12} {'plain now':>10} {'ratio':>6} {'model ' + ref:>12} "
          f"{'model now':>10} {'ratio':>6}")
    for case, (label, rows) in labels.items():
        cells = []
        for which in ("plain", "model"):
            before, after = best["ref"][(case, which)], best["this"][(case, which)]
            cells.append(f"{before:12.0f} {after:10.0f} {after / before:5.2f}x")
        name = re.sub(r"\s+", " ", label)
        print(f"{name:70.70} {rows:4d} {' '.join(cells)}")


if __name__ == "__main__":
    main()

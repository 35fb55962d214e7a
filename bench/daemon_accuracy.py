"""The daemon's own calibration, judged where a user would judge it: at rest, position by position.

Starts ``graytrack serve`` on a virtual rig (its own process, wall-clock speed), lets it calibrate
itself (the configured sweep and model), then moves the stage to a list of positions and, at each,
reads stream messages and prints the mean and std of ``error_um`` (tracked minus grating) next to the
mean Cramér–Rao bound, χ² and the share of messages flagged ``stale`` (with the reasons given). A model
that is right has a mean error near 0 everywhere and a std near the bound; a calibration that missed
something fixed to the print shows as a mean error that changes from position to position.

Run: .venv/bin/python bench/daemon_accuracy.py [--scenario lab] [--effects SPEC] [--sweep scan|stops]
     [--model auto|paper] [--messages 600]
"""

from __future__ import annotations

import argparse
import json
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np
from websockets.sync.client import connect

POSITIONS_MM = (0.1, 0.5, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 9.5, 10.0, 10.2, 10.36)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="lab")
    parser.add_argument("--effects", default="")
    parser.add_argument("--sweep", default="stops", choices=("stops", "scan"))
    parser.add_argument("--model", default="auto", choices=("auto", "paper"))
    parser.add_argument("--messages", type=int, default=600, help="stream messages read at each position")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="graytrack-accuracy-"))
    config = folder / "rig.toml"
    config.write_text(f'[camera]\nkind = "sim"\nscenario = "{args.scenario}"\neffects = "{args.effects}"\n'
                      f'[daemon]\ndata_dir = "{folder / "data"}"\nlog_level = "warning"\n'
                      f'[sweep]\nkind = "{args.sweep}"\nmodel = "{args.model}"\n')
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    daemon = subprocess.Popen([sys.executable, "-m", "graytrack", "serve", "--config", str(config), "--port",
                               str(port)])
    try:
        started = time.monotonic()
        while True:
            try:
                if httpx.get(f"{base}/healthz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if daemon.poll() is not None or time.monotonic() - started > 1800:
                raise SystemExit("the daemon did not come up tracking")
            time.sleep(1.0)
        status = httpx.get(f"{base}/api/status", timeout=5).json()
        print(f"rig {args.scenario} {args.effects}; sweep {args.sweep}, model {args.model}: calibrated in "
              f"{time.monotonic() - started:.0f} s; {status['calibration']['message']}")
        print(f"model: {status['model']}")
        auth = {"Authorization": f"Bearer {(folder / 'data' / 'token').read_text().strip()}"}
        print(f"{'position mm':>11} {'mean error µm':>13} {'std µm':>7} {'bound µm':>8} {'chi2':>5} {'stale %':>7}  "
              "reasons")
        means = []
        for target in POSITIONS_MM:
            httpx.post(f"{base}/api/stage/move", json={"target_mm": target}, headers=auth, timeout=5)
            time.sleep(2.0)
            with connect(f"ws://127.0.0.1:{port}/ws/position") as ws:
                messages = [json.loads(ws.recv()) for _ in range(args.messages)]
            error = np.array([m.get("error_um", np.nan) for m in messages], dtype=float)
            bound = np.nanmean([m["crlb_um"] for m in messages])
            chi2 = np.nanmean([m.get("chi2", np.nan) for m in messages])
            stale = [m for m in messages if m.get("stale")]
            reasons = sorted({str(m.get("stale_reason")) for m in stale})
            means.append(np.nanmean(error))
            print(f"{target:11.2f} {means[-1]:13.2f} {np.nanstd(error):7.2f} {bound:8.2f} {chi2:5.2f} "
                  f"{100 * len(stale) / len(messages):7.1f}  {','.join(reasons) or '-'}", flush=True)
        print(f"mean error over the positions: {min(means):+.2f} … {max(means):+.2f} µm")
    finally:
        daemon.terminate()
        daemon.wait(timeout=30)
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

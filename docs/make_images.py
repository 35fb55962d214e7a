"""docs/page.png and docs/report.png from a live daemon on the virtual rig (``make docs-images``).

The page is photographed in headless Chromium after a calibration and a move, so the picture shows
what a user sees: live position, the plots, the line view, history and events. The report plot
is the held-out error of that calibration against position, with its Cramér–Rao band, drawn from
the calibration's own recording with the same two-fold split the daemon reports.
"""

from __future__ import annotations

import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

DOCS = Path(__file__).resolve().parent
CHROMIUM = "/usr/bin/chromium"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            value = predicate()
            if value:
                return value
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise SystemExit(f"make_images: timed out waiting for {what}")


def report_plot(recording_path: Path, out: Path) -> None:
    """The held-out error of the calibration the daemon made with the default sweep (a scan)."""
    from graytrack.core.calibration import calibrate
    from graytrack.core.diagnosis.heldout import held_out_blocks, two_fold_by_block
    from graytrack.core.recording import load

    recording = load(recording_path)
    fig, ax = plt.subplots(figsize=(7, 3.2), dpi=150)
    folds = two_fold_by_block(recording, held_out_blocks(recording), lambda part: calibrate(part, "paper").model)
    for fold, color, label in zip(folds, ("#2b6cb0", "#b7791f"), ("even", "odd")):
        ax.fill_between(np.sort(fold.x_mm), -fold.crlb_um, fold.crlb_um, color="0.85", zorder=0)
        ax.plot(fold.x_mm, fold.error_um, "o", ms=2, color=color, label=f"held out: {label} blocks")
    ax.set_xlabel("stage position (mm)")
    ax.set_ylabel("error vs grating (µm)")
    ax.set_title("calibration: held-out error against position; grey: ±1 Cramér–Rao bound", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def main() -> None:
    from playwright.sync_api import sync_playwright

    folder = Path(tempfile.mkdtemp(prefix="graytrack-docs-"))
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    config = folder / "rig.toml"
    config.write_text(f'[daemon]\ndata_dir = "{folder / "data"}"\nlog_level = "warning"\n')
    daemon = subprocess.Popen([sys.executable, "-m", "graytrack", "serve", "--config", str(config), "--port",
                               str(port)])
    try:
        wait(lambda: httpx.get(f"{base}/healthz", timeout=2).status_code == 200, 300, "the first calibration")
        token = (folder / "data" / "token").read_text().strip()
        httpx.post(f"{base}/api/stage/move", json={"target_mm": 6.2}, headers={"Authorization": f"Bearer {token}"})
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=CHROMIUM, headless=True,
                                                 args=["--no-sandbox", "--disable-gpu",
                                                       "--disable-background-networking"])
            page = browser.new_page(viewport={"width": 1100, "height": 900}, device_scale_factor=1)
            page.goto(base + "/")
            page.wait_for_timeout(6000)
            page.screenshot(path=str(DOCS / "page.png"), full_page=True)
            browser.close()
        latest = httpx.get(f"{base}/api/calibrations", timeout=5).json()["items"][0]
        report_plot(folder / "data" / "calibrations" / latest["id"] / "recording.npz", DOCS / "report.png")
        print(f"wrote {DOCS / 'page.png'} and {DOCS / 'report.png'} (calibration {latest['id']}: "
              f"held-out {latest['error_std_um']:.2f} µm, bound {latest['bound_um']:.2f} µm)")
    finally:
        daemon.terminate()
        daemon.wait(timeout=30)
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()

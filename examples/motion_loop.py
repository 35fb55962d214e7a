"""A motion controller's loop on graytrack: calibrate if needed, visit targets, trust only fresh locked positions.

    .venv/bin/python examples/motion_loop.py http://127.0.0.1:8000 ~/.local/state/graytrack
"""

import sys

from graytrack.client import Client, GraytrackClientError

TARGETS_MM = (2.0, 7.5, 5.0)
ARRIVED_MM = 0.005  # within 5 µm of the target counts as there
MAX_AGE_MS = 100.0  # a position older than this at send time is not used for control


def main(url: str, data_dir: str, targets: tuple[float, ...] = TARGETS_MM, max_age_ms: float = MAX_AGE_MS) -> int:
    with Client(url, data_dir=data_dir) as daemon:
        # a daemon just started by `make run` calibrates itself: follow that, or start one if it has no model
        daemon.ensure_calibrated(progress=lambda fraction, message: print(f"calibrating {fraction:4.0%} {message}"))
        with daemon.stream(silence_s=1.0) as positions:
            try:
                for target in targets:
                    daemon.move(target)
                    for p in positions:
                        if p.gap:
                            print(f"missed {p.gap} messages before seq {p.seq}")
                        if not p.locked or p.stale or p.x_mm is None or (p.age_ms or 0.0) > max_age_ms:
                            daemon.stop()
                            print(f"seq {p.seq} not usable (locked {p.locked}, model stale: {p.stale_reason}, "
                                  f"age {p.age_ms} ms): stopped")
                            return 1
                        if abs(p.x_mm - target) < ARRIVED_MM:
                            print(f"at {target:g} mm: measured {p.x_mm:.4f} mm ± {p.crlb_um:.1f} µm")
                            break
            except GraytrackClientError as exc:  # refused, unreachable, or the stream fell silent
                daemon.stop()
                print(f"stopped: {exc}")
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2]))

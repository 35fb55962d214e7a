"""The processes that track frame by frame run BLAS on one thread (service/blas.py)."""

from __future__ import annotations

import subprocess
import sys


def test_the_daemon_and_track_limit_blas_to_one_thread() -> None:
    """In a fresh interpreter (the limit is process-wide): BLAS starts with the machine's threads
    (forced to 2 here), and after the call every BLAS library numpy loaded runs one."""
    code = (
        "from threadpoolctl import threadpool_info\n"
        "from graytrack.service.blas import single_threaded_blas\n"
        "before = single_threaded_blas()\n"
        "after = [p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas']\n"
        "print(before, after)\n"
    )
    env = {"OPENBLAS_NUM_THREADS": "2", "PATH": ""}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env=env).stdout.split(maxsplit=1)
    assert int(out[0]) == 2
    threads = [int(n) for n in out[1].strip(" []\n").split(",")]
    assert threads and set(threads) == {1}

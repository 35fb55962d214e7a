"""The Dask side of graytrack: a client on a local cluster of processes, or on a running scheduler.

Dask is the ``cluster`` extra. Everything that needs it comes through :func:`dask_client`, so a
missing install is one sentence on how to fix it, raised before any work starts.
"""

from __future__ import annotations

import argparse
import logging
import os
from contextlib import contextmanager
from typing import Any, Iterator

from graytrack.service.errors import CliError

INSTALL_HINT = "this needs Dask, the cluster extra: pip install 'graytrack[cluster]'"
CONNECT_TIMEOUT_S = 20.0


def add_cluster_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="submit to a running Dask scheduler (tcp://HOST:8786); "
                             "default: a local cluster of processes")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="local cluster: worker processes (default: one per core); "
                             "with --scheduler: wait until N workers are connected")


def distributed_module() -> Any:
    """``dask.distributed``, or a one-line :class:`CliError` saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise CliError(INSTALL_HINT) from None
    return distributed


@contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None) -> Iterator[Any]:
    """A connected ``distributed.Client``; the local cluster it started (if any) is closed after."""
    distributed = distributed_module()
    if workers is not None and workers < 1:
        raise CliError(f"--workers must be at least 1, got {workers}")
    cluster = None
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError) as exc:
            raise CliError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
    else:
        # One single-threaded process per worker: the numerics hold the GIL, threads would queue.
        cluster = distributed.LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                           processes=True, host="127.0.0.1", dashboard_address=None,
                                           silence_logs=logging.ERROR)
        client = distributed.Client(cluster)
    try:
        if scheduler and workers:
            client.wait_for_workers(workers, timeout=CONNECT_TIMEOUT_S)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()

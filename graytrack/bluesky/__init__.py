"""The graytrack daemon in bluesky: an ophyd-async encoder (detector) and stage (movable).

Needs the ``bluesky`` extra (``pip install 'graytrack[bluesky]'``; in a checkout
``.venv/bin/pip install -e '.[bluesky]'``); the rest of graytrack imports without it. ::

    from bluesky import RunEngine
    import bluesky.plans as bp
    from ophyd_async.core import init_devices
    from graytrack.bluesky import GraytrackEncoder, GraytrackStage

    RE = RunEngine()
    with init_devices():
        encoder = GraytrackEncoder("http://127.0.0.1:8000", data_dir="/var/lib/graytrack")
        stage = GraytrackStage("http://127.0.0.1:8000", data_dir="/var/lib/graytrack")
    RE(bp.scan([encoder], stage, 2.0, 4.0, 3))
"""

try:
    import ophyd_async  # noqa: F401
except ImportError as exc:  # one sentence instead of a traceback into the first missing name
    raise ImportError("graytrack.bluesky needs the bluesky extra: pip install 'graytrack[bluesky]'") from exc

from graytrack.bluesky.encoder import GraytrackEncoder
from graytrack.bluesky.stage import GraytrackStage

__all__ = ["GraytrackEncoder", "GraytrackStage"]

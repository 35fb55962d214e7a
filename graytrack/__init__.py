"""graytrack: a camera and a printed sine target as a linear displacement sensor.

The subpackages map to the repository's top-level folders: ``graytrack.core`` (numerics, no I/O
beyond the recording format), ``graytrack.drivers`` (camera, stage, virtual rig),
``graytrack.service`` (daemon and command line) and ``graytrack.web`` (status page).
"""

__version__ = "0.1.0"

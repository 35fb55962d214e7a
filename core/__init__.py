"""Pure numerics of graytrack: gray-level models, calibration, tracking, noise floor, recordings.

Nothing here does I/O (except reading and writing the recording format) or starts threads, and
nothing here imports from ``graytrack.drivers`` or ``graytrack.service``: data flows one way,
drivers -> service -> core.
"""

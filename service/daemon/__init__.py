"""The daemon (``graytrack serve``): owns camera and stage, calibrates itself, streams positions.

One module per job: ``settings`` (the TOML file), ``storage`` (the data directory), ``grating``
(POS? polling and pairing by host time), ``acquisition`` (the frame loop), ``sweep`` (the
calibration sweep), ``rig`` (lifecycle and state), ``broadcast`` (thread → WebSocket fan-out),
``metrics`` (Prometheus text) and ``app`` (the HTTP interface of docs/contracts.md).
"""

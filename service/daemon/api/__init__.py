"""The HTTP interface, one router per resource (status, calibration, stage, stream, pages)."""

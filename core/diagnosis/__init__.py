"""The closed loop: find the residual a model leaves, trace it to a physical effect, add the effect,
and report held-out figures before and after (``graytrack diagnose``)."""

from graytrack.core.diagnosis.loop import DiagnosisResult, diagnose

__all__ = ["DiagnosisResult", "diagnose"]

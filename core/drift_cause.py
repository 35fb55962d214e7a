"""What drifted the line camera − grating: a lens, a grown print, or neither (the grating or the mount).

Once the line has drifted (core/reference_monitor.py) two figures say whose the drift is: the image's
stretch across the pixels since calibration (the magnification watch's mean ± σ, core/watches/magnification.py)
and the line's scale since calibration (± σ). Each cause predicts both:

- a **lens** whose magnification changed by m stretches the image by m (drawn from
  :data:`~graytrack.core.watches.magnification.CHANGE_PRIOR_PPM`) and slides it by m × the axis's distance,
  the same all along the stroke; what of the slide the line reads as a scale while the stage sweeps (its
  growth in time over the speed) may be anything up to :data:`SCALE_SPAN_PPM`, and has nothing to do with
  the stretch;
- a **print** grown by g reads the scale −g and stretches its image by the same −g (g up to
  :data:`SCALE_SPAN_PPM`): the two figures agree;
- **neither** (a camera moved on its mount, a stage re-homed, the grating's own scale warming): no
  stretch, and a scale no larger than :data:`GRATING_SCALE_PPM`.

Why the scale counts: a stage that sweeps the stroke at a steady speed in one direction makes time and
position the same regressor (on the paper rig's bench pass their correlation is 1.000), so camera − grating
alone cannot tell a slide growing in time from a slope along the stroke. But no grating or mount makes a
scale of thousands of ppm without stretching the image, and a grown print that did would stretch it by as
much: a scale of −2100 ± 490 ppm with a stretch of 190 ± 280 (the paper rig's 0.15 % lens ramp at its
frame 59) is a lens's, while its stretch alone stays within 2σ of none until frame ~230.

Each figure is Gaussian about what the cause predicts, so every likelihood is in closed form.
"""

from __future__ import annotations

import math

from graytrack.core.watches.magnification import CHANGE_PRIOR_PPM

# σ of the scale camera − grating may take since calibration with the image unstretched: a grating's
# own scale warming (glass ~8, steel ~11 ppm/K) over ~10 K; a camera moved on its mount or a stage
# re-homed shift the line, they do not tilt it
GRATING_SCALE_PPM = 100.0
# σ of the scale a lens's slide or a print's growth may give the line (1 %: a print's growth in humidity is
# hundreds of ppm, a slide's growth over the stage's speed thousands); the same for both, so it weighs
# only against neither
SCALE_SPAN_PPM = 10000.0


def explanations(mean_ppm: float, sigma_ppm: float, scale_ppm: float, scale_var_ppm2: float) -> dict[str, float]:
    """The log-likelihood (its common constant dropped) of a stretch mean ± ``sigma_ppm`` and a line's
    scale ± √``scale_var_ppm2`` since calibration under each cause: ``"lens"``, ``"print"``, ``"none"``.
    A scale that is not finite (no line) leaves the stretch alone to tell, and no print."""
    var = sigma_ppm * sigma_ppm
    change, span, grating = CHANGE_PRIOR_PPM ** 2, SCALE_SPAN_PPM ** 2, GRATING_SCALE_PPM ** 2
    if not math.isfinite(scale_ppm):
        return {"lens": _log_normal(mean_ppm, var + change), "print": -math.inf, "none": _log_normal(mean_ppm, var)}
    return {"lens": _log_normal2(mean_ppm, scale_ppm, var + change, 0.0, scale_var_ppm2 + span),
            "print": _log_normal2(mean_ppm, scale_ppm, var + span, span, scale_var_ppm2 + span),
            "none": _log_normal2(mean_ppm, scale_ppm, var, 0.0, scale_var_ppm2 + grating)}


def lens_favoured(mean_ppm: float, sigma_ppm: float, scale_ppm: float, scale_var_ppm2: float) -> bool:
    """Whether a lens explains the stretch and the line's scale better than a grown print and than
    neither (:func:`explanations`: the highest of the three likelihoods, the causes equally likely
    before the frames tell)."""
    if not (math.isfinite(mean_ppm) and math.isfinite(sigma_ppm) and sigma_ppm > 0.0):
        return False
    told = explanations(mean_ppm, sigma_ppm, scale_ppm, scale_var_ppm2)
    return told["lens"] > max(told["print"], told["none"])


def _log_normal(residual: float, variance: float) -> float:
    """log of the normal density of ``residual`` with ``variance`` (its constant dropped)."""
    return -0.5 * (residual * residual / variance + math.log(variance))


def _log_normal2(a: float, b: float, var_a: float, cov: float, var_b: float) -> float:
    """log of the bivariate normal density of (``a``, ``b``) about zero with covariance
    ((``var_a``, ``cov``), (``cov``, ``var_b``)) (its constant dropped)."""
    det = var_a * var_b - cov * cov
    return -0.5 * ((var_b * a * a - 2.0 * cov * a * b + var_a * b * b) / det + math.log(det))

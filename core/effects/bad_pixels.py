"""Bad pixels: stuck, dead, hot, noisy, or not following the target. Found, named and masked.

A pixel that does not see the target is worse than useless to a least-squares fit: a pixel stuck
at full scale in a line of 100 pulls a cubic pixel polynomial far off and, in tracking, drags
every frame's position. Most defects show without any model, in the pixel's own time series
(it does not move, it sits far off its neighbours, it is noisier than the photon-transfer curve
allows); the rest show as a residual far above noise once a model is fitted. Found pixels get
weight 0 in calibration and in the model (``pixel_weight``), and are named with their (row,
pixel) and the reason.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.ndimage import median_filter

from graytrack.core.effects import Effect
from graytrack.core.noise import temporal_differences
from graytrack.core.regression import weighted_affine
from graytrack.core.evidence import Evidence

STUCK_SHARE = 0.05  # temporal spread below this share of a typical pixel's: the pixel does not see the light
OUTLIER_Z = 10.0  # robust z-score (MAD) beyond which a pixel stands out from the others
HOT_MIN_SIGMAS = 10.0  # an offset must also exceed this many noise σ to count
NOISY_RATIO = 4.0  # temporal variance this many times what the noise curve allows
FOLLOW_RATIO = 9.0  # residual variance this many times the noise: the pixel does not follow the target
NEIGHBOURS = 7
# More of the line than this failing is no pixel defect but the print, the light or the optics (dust
# across a 16-row strip had 476 of its 1,600 pixels "not follow the target", in every one of its 100
# columns): a mask would leave the model blind, with a calibration χ² of 0, and its trial tracked nothing.
MAX_MASKED_SHARE = 0.2

Finding = tuple[int, int, str]  # (row, pixel, reason)


def _robust_z(values: np.ndarray, good: np.ndarray) -> np.ndarray:
    centre = np.median(values[good])
    scale = 1.4826 * np.median(np.abs(values[good] - centre))
    return (values - centre) / max(scale, 1e-12)


def model_free_bad_pixels(frames: np.ndarray, reference: np.ndarray | None, period_mm: float | None,
                          sigma_gray: float, variance_at: Any = None,
                          transients: np.ndarray | None = None) -> list[Finding]:
    """Stuck, dead, hot and noisy pixels of frames ``(K, R, n)``, from their time series alone.

    ``variance_at(gray)`` is the noise curve (σ² at a gray level); default σ² = ``sigma_gray``².
    ``transients`` (bool, like ``frames``) are samples a glint or passing dust spoiled: a pixel is
    judged on the frames where nothing passed over it (core/transients.py).
    """
    frames = np.asarray(frames, dtype=np.float64)
    mean, spread = frames.mean(axis=0), frames.std(axis=0)
    typical = float(np.median(spread))
    found: dict[tuple[int, int], str] = {}
    floor = float(frames.min())
    for r, u in zip(*np.nonzero(spread < STUCK_SHARE * typical)):
        value = float(mean[r, u])
        found[(int(r), int(u))] = (f"dead (stuck at the floor, {value:g})" if value <= floor + 0.5
                                   else f"stuck at {value:g} (does not see the light)")
    good = np.ones(mean.shape, dtype=bool)
    for r, u in found:
        good[r, u] = False
    local = median_filter(mean, size=(1, NEIGHBOURS), mode="nearest")
    offset = mean - local
    z = _robust_z(offset, good)
    for r, u in zip(*np.nonzero((np.abs(z) > OUTLIER_Z) & (np.abs(offset) > HOT_MIN_SIGMAS * sigma_gray) & good)):
        kind = "hot" if offset[r, u] > 0 else "dark"
        found[(int(r), int(u))] = f"{kind} (offset {offset[r, u]:+.1f} gray from its neighbours)"
        good[r, u] = False
    cleaned, level, gain, _ = temporal_differences(frames, reference, period_mm, transients)
    shape = frames.shape[1:]
    if transients is None:
        temporal = (np.mean(cleaned**2, axis=0) / gain**2).reshape(shape)
    else:
        clear = np.isfinite(cleaned)
        squares = np.where(clear, cleaned, 0.0) ** 2
        temporal = (squares.sum(axis=0) / np.maximum(clear.sum(axis=0), 1) / gain**2).reshape(shape)
        level = (np.where(clear, level, 0.0).sum(axis=0) / np.maximum(clear.sum(axis=0), 1))[None]
    expected = (np.full(shape, sigma_gray**2) if variance_at is None
                else variance_at(level.mean(axis=0).reshape(shape)))
    ratio = temporal / np.maximum(expected, 1e-12)
    z = _robust_z(ratio, good)
    for r, u in zip(*np.nonzero((ratio > NOISY_RATIO) & (z > OUTLIER_Z) & good)):
        found[(int(r), int(u))] = f"noisy (σ {np.sqrt(temporal[r, u]):.1f} gray, the noise curve allows " \
                                  f"{np.sqrt(expected[r, u]):.1f})"
    return sorted((r, u, reason) for (r, u), reason in found.items())


def residual_bad_pixels(residual: np.ndarray, predicted: np.ndarray, usable: np.ndarray,
                        sigma_gray: float) -> list[Finding]:
    """Pixels whose fit residual ``(K, R, n)`` is far above noise and far above the other pixels',
    after a gain and offset per pixel: what such a response explains is the flat field's, not a
    defect."""
    predicted = np.broadcast_to(predicted, residual.shape)
    gain, offset = weighted_affine(residual, predicted, usable, axis=(0,))
    residual = (residual - gain * predicted - offset) * usable
    count = np.maximum(usable.sum(axis=0), 1.0)
    variance = (residual**2).sum(axis=0) / count
    good = usable.max(axis=0) > 0
    if not good.any():
        return []
    z = _robust_z(variance, good)
    hits = (variance > FOLLOW_RATIO * sigma_gray**2) & (z > OUTLIER_Z) & good
    return [(int(r), int(u), f"does not follow the target (residual {np.sqrt(variance[r, u]):.1f} gray rms, "
             f"noise {sigma_gray:.2f})") for r, u in zip(*np.nonzero(hits))]


def find_bad_pixels(data: Any) -> list[Finding]:
    """Every bad pixel calibration data shows without a model (a fit's residual adds those that do not
    follow the target: :func:`residual_bad_pixels`, which the probe runs on the fit it has)."""
    noise = getattr(data, "pixel_noise", None)
    return sorted(model_free_bad_pixels(data.frames, data.x_mm, data.meta.get("period_mm"), data.sigma_gray,
                                        None if noise is None else noise.variance, getattr(data, "transients", None)))


def masked_share(findings: Any, shape: tuple[int, int], per_row: bool) -> float:
    """The share of what a model sees that ``findings`` would mask: pixels of a per-row model,
    columns of a shared one (it averages the rows, and a bad pixel takes its column)."""
    if per_row:
        return len({(r, u) for r, u, _ in findings}) / float(shape[0] * shape[1])
    return len({u for _, u, _ in findings}) / float(shape[1])


def mask(findings: Any, shape: tuple[int, int]) -> np.ndarray:
    """``(R, n)``: 0 at the listed pixels, 1 elsewhere."""
    weights = np.ones(shape)
    for r, u, _ in findings:
        weights[r, u] = 0.0
    return weights


class BadPixels(Effect):
    name = "bad_pixels"
    frame_part = "mask"  # core/frame_tables.py: what tracking reads of it
    family = "pixels that do not see the target (stuck, dead, hot, noisy, a defect that does not follow the light)"
    adds = "weight 0 for those pixels in calibration and tracking; their indices and reasons in the report"
    fitted = ("model-free tests of each pixel's time series (spread, offset from its neighbours, noise against the "
              "photon-transfer curve), then the fit's residual per pixel")
    order = 1
    data_quality = True

    def probe(self, stage):
        from graytrack.core.geometry_check import MIN_SEEN_SHARE  # a model that sees less is refused

        train, val = stage.train, stage.val
        known = {(r, u) for r, u, _ in stage.spec.get(self.name, ())}
        residual = train.data.frames - np.broadcast_to(train.predicted, train.data.frames.shape)
        model_free = [f for f in find_bad_pixels(train.data) if f[:2] not in known]
        taken = known | {f[:2] for f in model_free}
        found = sorted(model_free + [f for f in residual_bad_pixels(residual, train.predicted, train.usable,
                                                                     train.data.sigma_gray) if f[:2] not in taken])
        shape = train.data.frames.shape[1:]
        if masked_share(found, shape, stage.spec.per_row) > MAX_MASKED_SHARE:
            found = model_free  # the residual's findings are a pattern of the scene, not of pixels
        # A pixel that fails on its own time series (stuck, dead, hot, noisy) is masked however many
        # share its fault, while the model keeps enough of the line to see the period: a ROI 30 %
        # past the print's edge has 30 % of its columns stuck at the surface's light, and the loop
        # that left them in grew three pixel polynomials and a flat field around the step, 9.5×
        # its bound on the run where `graytrack calibrate` masked them, 1.07×.
        if not found or masked_share(found, shape, stage.spec.per_row) > 1.0 - MIN_SEEN_SHARE:
            return None
        shape = val.data.frames.shape[1:]
        spoiled = 1.0 - mask(found, shape)
        raw = (val.data.frames - val.predicted) * spoiled
        explained = float((raw**2).sum())
        sigma2 = val.data.sigma_gray**2
        n_samples = max(float(spoiled.sum()) * val.data.frames.shape[0], 1.0)
        z = (explained / sigma2 - n_samples) / np.sqrt(2.0 * n_samples)
        named = "; ".join(f"({r}, {u}) {reason}" for r, u, reason in found[:8])
        more = f" and {len(found) - 8} more" if len(found) > 8 else ""
        return Evidence(self.name, "pixel (single)", explained, float(z), 1.0,
                        f"{len(found)} pixel(s) do not see the target as the others do: {named}{more}",
                        tuple(found))

    def screen(self, data):
        return tuple(find_bad_pixels(data)) or None

    def grow(self, spec, argument):
        if not argument:
            return None
        return spec.set(self.name, tuple(sorted(set(spec.get(self.name, ())) | set(argument))))

    def prepare_data(self, setting, data):
        return data.with_weights(data.weights * mask(setting, data.frames.shape[1:]))

    def finish(self, setting, state, model):
        weight = np.ones((model.n_rows, model.n_pixels))
        for r, u, _ in setting:
            weight[r if model.n_rows > 1 else 0, u] = 0.0  # a shared model averages the rows: the column goes
        listed = [{"row": r, "pixel": u, "reason": reason} for r, u, reason in setting]
        return model.with_changes(coeffs=model.coeffs, pixel_weight=weight, info={**model.info, "bad_pixels": listed})

    def report(self, setting):
        return [{"row": r, "pixel": u, "reason": reason} for r, u, reason in setting]


EFFECT = BadPixels()

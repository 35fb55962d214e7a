"""Frames that went through JPEG (an MJPEG camera stream): found from the frames, and the bound
they still allow.

A JPEG decoder's output, cut into the encoder's 8×8 blocks, has DCT coefficients on multiples of
the quantisation table's steps (to within the final rounding to 8 bits); raw frames have them
anywhere. The quality is the lowest whose standard table (T.81 K.1, IJG scaling) puts the
low-frequency coefficients on its lattice, well beyond what chance gives.

What the compression costs: a coefficient quantised with step q carries, besides the sensor's noise
σ², an error of about q²/12 that the model cannot know (it depends on the image and its noise in a
way no calibration repeats). The Cramér–Rao bound of white noise, σ/√Σ(∂F/∂x)², then promises
more than the frames hold; the bound with the quantisation, computed on the DCT of the slope, is
what a tracker can reach on such a stream. On the lab rig at quality 75 it is 2.5× the white one.
Where the steps are several times the sensor's σ the q²/12 picture no longer holds (no noise dithers
the rounding): calibration replays its model's images through the stream (:func:`round_trip`,
core/adequacy.py ``replayed_factor``) and the bound carries the larger of the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BLOCK = 8
# ITU-T T.81 Table K.1: luminance quantisation table at quality 50.
LUMINANCE_TABLE = np.array([
    [16, 11, 10, 16, 24, 40, 51, 61],
    [12, 12, 14, 19, 26, 58, 60, 55],
    [14, 13, 16, 24, 40, 57, 69, 56],
    [14, 17, 22, 29, 51, 87, 80, 62],
    [18, 22, 37, 56, 68, 109, 103, 77],
    [24, 35, 55, 64, 81, 104, 113, 92],
    [49, 64, 78, 87, 103, 121, 120, 101],
    [72, 92, 95, 98, 112, 100, 103, 99],
], dtype=np.float64)


def quantisation_table(quality: float) -> np.ndarray:
    """The luminance table an encoder uses at ``quality`` (1…100), each step in 1…255."""
    quality = float(np.clip(quality, 1.0, 100.0))
    scale = 5000.0 / quality if quality < 50.0 else 200.0 - 2.0 * quality
    return np.clip(np.floor((LUMINANCE_TABLE * scale + 50.0) / 100.0), 1.0, 255.0)


def _dct_matrix() -> np.ndarray:
    """Orthonormal 8-point DCT-II: ``C @ block @ C.T`` is the 2-D transform."""
    k = np.arange(BLOCK)[:, None]
    n = np.arange(BLOCK)[None, :]
    matrix = np.sqrt(2.0 / BLOCK) * np.cos(np.pi * (2 * n + 1) * k / (2 * BLOCK))
    matrix[0] /= np.sqrt(2.0)
    return matrix


DCT = _dct_matrix()


LOW_FREQUENCY = [(u, v) for u in range(3) for v in range(3) if u + v <= 2]  # where a smooth image has energy
LATTICE_TOLERANCE = 1.0  # 8-bit rounding moves an orthonormal coefficient by ~0.3 rms
MIN_SCORE = 0.7  # share of a coefficient's values on the lattice beyond chance
MIN_STEP, MAX_STEP = 3, 64  # smaller steps put everything near the lattice: no evidence either way
MIN_POSITIONS = 3  # low-frequency coefficients whose step was found
MIN_VALUES = 50  # values off zero a coefficient needs for its lattice to count


@dataclass(frozen=True)
class JpegFinding:
    quality: int
    score: float  # 0 … 1, on the lattice beyond chance
    table: np.ndarray  # (8, 8) quantisation steps


def block_dct(images: np.ndarray, level_shift: float = 0.0) -> np.ndarray:
    """DCT coefficients of every whole 8×8 block of images ``(K, R, n)`` from their corner:
    ``(K, R//8, n//8, 8, 8)``. JPEG shifts 8-bit codes by 128 first (``level_shift``)."""
    values = np.asarray(images, dtype=np.float64)
    k, rows, width = values.shape
    by, bx = rows // BLOCK, width // BLOCK
    blocks = values[:, :by * BLOCK, :bx * BLOCK].reshape(k, by, BLOCK, bx, BLOCK) - level_shift
    return np.einsum("ij,kajbl,ml->kabim", DCT, blocks, DCT)


def round_trip(codes: np.ndarray, table: np.ndarray) -> np.ndarray:
    """8-bit codes ``(K, R, n)`` through a baseline JPEG's luminance path with quantisation
    ``table`` and back, as float64 codes: the 8×8 DCT from the frame's corner (a partial block at
    the edge padded by repeating its last row or column, as encoders do), each coefficient rounded
    to its step, the inverse, rounded and clipped to 0…255 (the entropy coding is lossless)."""
    values = np.asarray(codes, dtype=np.float64)
    k, rows, width = values.shape
    padded = np.pad(values, ((0, 0), (0, -rows % BLOCK), (0, -width % BLOCK)), mode="edge") - 128.0
    blocks = padded.reshape(k, padded.shape[1] // BLOCK, BLOCK, padded.shape[2] // BLOCK, BLOCK)
    coefficients = np.einsum("ij,kajbl,ml->kaibm", DCT, blocks, DCT)  # (K, by, 8, bx, 8)
    steps = np.asarray(table, dtype=np.float64)[None, None, :, None, :]
    restored = np.einsum("ji,kajbl,lm->kaibm", DCT, np.rint(coefficients / steps) * steps, DCT)
    return np.clip(np.rint(restored.reshape(padded.shape)[:, :rows, :width] + 128.0), 0.0, 255.0)


def _lattice_score(values: np.ndarray, step: float, tolerance: float = LATTICE_TOLERANCE) -> float:
    """How much more of ``values`` sits on multiples of ``step`` than chance puts there (0 … 1).
    Values within half a step of zero sit on every lattice and say nothing: left out."""
    values = values[np.abs(values) > 0.5 * step]
    if values.size < MIN_VALUES or 2.0 * tolerance >= step:
        return float("nan")
    on = float((np.abs(values - step * np.round(values / step)) <= tolerance).mean())
    chance = 2.0 * tolerance / step
    return (on - chance) / (1.0 - chance)


def _rows_agree(coefficients: np.ndarray) -> bool:
    """Whether nearly every block's rows agree exactly: no sensor's noise does that, a stream that
    zeroed the vertical noise of a strip whose rows see the same print does."""
    flat = np.abs(coefficients[:, 1:, :]).max(axis=(1, 2)) < 1e-6
    return bool(flat.size and flat.mean() > 0.9)


def find_jpeg(frames: np.ndarray, max_frames: int = 200) -> JpegFinding | None:
    """The JPEG quality the frames were compressed at, or None (raw frames, or no whole block).

    Each low-frequency coefficient's step is the largest whose lattice its values sit on (half
    the step fits as well, twice the step does not); the quality is the one whose table has those
    steps.

    Independent per-pixel rounding by the decoder moves an orthonormal coefficient ~0.3 rms off
    its lattice. Where every block's rows agree exactly, the rounding errors agree down each column
    too and add coherently, √8 times more: a second look with a wider tolerance, and the rows'
    agreement itself counting as one of the positions the evidence needs.
    """
    frames = np.asarray(frames)
    if frames.ndim < 3 or frames.shape[-2] < BLOCK or frames.shape[-1] < BLOCK:
        return None
    sample = frames[::max(1, frames.shape[0] // max_frames)].reshape((-1,) + frames.shape[-2:])
    coefficients = block_dct(sample, 128.0).reshape(-1, BLOCK, BLOCK)
    found = _lattice_finding(coefficients, LATTICE_TOLERANCE, MIN_POSITIONS)
    if found is None and _rows_agree(coefficients):
        found = _lattice_finding(coefficients, np.sqrt(2.0) * LATTICE_TOLERANCE, MIN_POSITIONS - 1)
    return found


def _lattice_finding(coefficients: np.ndarray, tolerance: float, positions: int) -> JpegFinding | None:
    """The quality whose table fits the steps found at ``positions`` or more low frequencies."""
    steps: dict[tuple[int, int], float] = {}
    for u, v in LOW_FREQUENCY:
        fitting = [step for step in range(MIN_STEP, MAX_STEP + 1)
                   if _lattice_score(coefficients[:, u, v], step, tolerance) >= MIN_SCORE]
        if fitting:
            steps[(u, v)] = float(max(fitting))
    if len(steps) < positions:
        return None
    where = tuple(np.array(list(steps)).T)
    found = np.array(list(steps.values()))
    mismatch = [float(np.abs(np.log(quantisation_table(q)[where] / found)).sum()) for q in range(1, 101)]
    quality = 1 + int(np.argmin(mismatch))
    table = quantisation_table(quality)
    score = float(np.nanmean([_lattice_score(coefficients[:, u, v], table[u, v], tolerance) for u, v in steps]))
    return JpegFinding(quality, score, table) if score >= MIN_SCORE else None


def bound_with_quantisation_mm(slope: np.ndarray, sigma2: float | np.ndarray, table: np.ndarray) -> np.ndarray:
    """Cramér–Rao bound per frame ``(K,)`` in mm for frames ``(K, R, n)`` of a JPEG stream: each
    coefficient of the slope's block DCT against σ² + q²/12 (whole blocks only)."""
    coefficients = block_dct(slope)
    information = (coefficients**2 / (np.mean(sigma2) + table**2 / 12.0)).sum(axis=(1, 2, 3, 4))
    return 1.0 / np.sqrt(np.maximum(information, 1e-300))


def bound_factor(slope: np.ndarray, sigma2: float | np.ndarray, table: np.ndarray) -> float:
    """How much the stream's quantisation widens the bound: the rms over frames of
    :func:`bound_with_quantisation_mm` over the white-noise bound, both on the same whole blocks of
    the slope ``(K, R, n)`` (1 when nothing is quantised: the orthonormal DCT keeps Σ(∂F/∂x)²).

    One figure per model rather than one per position: it scales the tracker's per-frame bound
    without a second evaluation in the frame loop, and its rms is what the run's error is held to.
    """
    rows, width = slope.shape[-2] // BLOCK * BLOCK, slope.shape[-1] // BLOCK * BLOCK
    if rows == 0 or width == 0:
        return 1.0
    whole = np.asarray(slope, dtype=np.float64)[..., :rows, :width]
    white2 = np.mean(sigma2) / np.maximum((whole**2).sum(axis=(-2, -1)), 1e-300)
    stream2 = bound_with_quantisation_mm(whole, sigma2, table) ** 2
    return float(np.sqrt(np.mean(stream2) / np.mean(white2)))


def stream_bound_factor(info: dict) -> float:
    """The factor a model's calibration found for its frames' stream (1: raw frames)."""
    return float((info.get("stream") or {}).get("bound_factor") or 1.0)


def stream_chi2_spread(info: dict) -> float:
    """How much wider than white noise's the calibration's frames' χ² spread on a model's stream, one
    frame to the next (1: raw frames). The quantisation's error sits in a few coarse coefficients per
    block, not spread over every sample: on the `lab` strip at quality 75 a frame's χ² scatters 10 %
    about its level where 2,048 samples of white noise scatter it 3.1 %, and a frame beyond 5 of the
    white spreads (a blur suspected, the focus tried) was one in fourteen of a steady run."""
    return float((info.get("stream") or {}).get("chi2_spread") or 1.0)


def judged_factor(info: dict) -> float:
    """The factor a model's own calibration error is judged against (inadequacy, the local profile,
    whether its focus is followed): the quantisation's q²/12 figure, the stricter of the two a
    calibration finds (1: raw frames). The positions carry :func:`stream_bound_factor`, the stream
    replayed as the tracker meets it; judged against that, the seed model on the lab strip at
    quality 75 (its own frames 6.2 white bounds off, 1.8x the replay's 3.4) would pass as adequate
    and its runs sit 1.9x their bound with 2.3 % of their frames 4+ bounds off unflagged."""
    stream = info.get("stream") or {}
    return float(stream.get("quantisation_factor") or stream.get("bound_factor") or 1.0)

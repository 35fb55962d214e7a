"""The residual's shares by family: the one-Gram projection gives a least-squares solver's numbers,
degenerate shapes included, and the χ² watch looks at a sample of a long suspect run only."""

import numpy as np
import pytest

from graytrack.core import attribution
from graytrack.core.watches import chi2 as chi2_watch
from graytrack.core.watches.chi2 import EXPLAIN_EVERY, ChiSquareWatch


def reference_shares(residual, weights, columns):
    """Each family fitted on its own with a least-squares solver, as the definition reads."""
    used = weights > 0
    root = np.sqrt(weights[used])
    z = residual[used] * root
    excess = float(z @ z) - z.size
    shares, coefficients = {}, {}
    shift = columns["shift"][used] * root[:, None]
    for family in ("light", "focus", "print"):
        basis = np.concatenate([columns[family][used] * root[:, None], shift], axis=1)
        fitted, *_ = np.linalg.lstsq(basis, z, rcond=None)
        explained = float(np.sum((basis @ fitted) ** 2))
        shares[family] = float(np.clip((explained - basis.shape[1]) / excess, 0.0, 1.0))
        coefficients[family] = fitted[:-1]
    return shares, coefficients


def frame(n_rows, n_pixels, flat=False):
    u = np.tile(np.linspace(0.0, 1.0, n_pixels), n_rows)
    values = np.full(u.size, 128.0) if flat else 128 + 80 * np.sin(9.0 * u) + 12 * np.sin(27.0 * u + 0.3)
    slopes = 720 * np.cos(9.0 * u)
    curvature = -6480 * np.sin(9.0 * u)
    return values, slopes, curvature, 9.0 * u


@pytest.mark.parametrize("n_rows, n_pixels, flat", [(1, 200, False), (16, 128, False), (1, 120, True)])
def test_shares_are_the_least_squares_projections(n_rows, n_pixels, flat):
    rng = np.random.default_rng(n_rows + n_pixels)
    values, slopes, curvature, phase = frame(n_rows, n_pixels, flat)
    columns = attribution.shapes(values, slopes, curvature, n_rows, phase, 5)
    # the shapes: a Legendre light across each row and the print's harmonics, as written out
    u = np.tile(np.linspace(-1.0, 1.0, n_pixels), n_rows)
    assert np.allclose(columns["light"][:, 2] / values, 1.5 * u * u - 0.5)
    assert np.allclose(columns["print"][:, 4], np.cos(5 * phase), atol=1e-12)
    assert np.allclose(columns["print"][:, 9], np.sin(5 * phase), atol=1e-12)
    weights = np.full(values.size, 1.0 / 0.7**2)
    weights[[3, 40]] = 0.0  # masked samples take no part
    for trial in range(4):
        residual = rng.normal(0.0, 0.7, values.size) + 0.05 * trial * values * u**2 + 0.002 * (trial % 2) * curvature
        residual[7] += 30.0
        got, got_coefficients = attribution.shares(residual, weights, columns)
        want, want_coefficients = reference_shares(residual, weights, columns)
        assert got["pixels"] > 0.0
        for family in want:
            assert got[family] == pytest.approx(want[family], abs=1e-9)
            if not flat:  # a flat line leaves gain and offset one shape: only the projection is defined
                assert np.allclose(got_coefficients[family], want_coefficients[family], rtol=1e-7, atol=1e-9)


def test_a_long_suspect_run_is_explained_on_a_sample_of_its_frames():
    watch = ChiSquareWatch()
    asked = []

    def explain():
        asked.append(len(asked))
        return {"shares": {"light": 0.9, "pixels": 0.1}, "coefficients": {"light": np.ones(6)}, "top": [1, 2]}

    for _ in range(50):
        watch.step(True, False, explain)
    assert len(asked) == 50 // EXPLAIN_EVERY  # the first suspect frame, then every EXPLAIN_EVERY-th
    assert watch.step(True, True, explain) == "light"  # named from the sample when the model goes stale
    watch.step(False, False, explain)
    assert watch.shares == {}  # a suspect run over: what it learnt is forgotten


def test_a_run_suspect_for_long_is_looked_at_ever_less_often_until_it_goes_stale():
    """A window of looks every EXPLAIN_EVERY frames, then half as often after each window learnt,
    down to one in EXPLAIN_EVERY_LONGEST; every EXPLAIN_EVERY-th again once stale, and from the
    start in the next suspect run."""
    watch = ChiSquareWatch()
    asked: list[int] = []
    frame = 0

    def explain():
        asked.append(frame)
        return {"shares": {"light": 0.9}, "coefficients": {"light": np.ones(6)}, "top": [1]}

    def run(frames: int, stale: bool = False) -> list[int]:
        nonlocal frame
        start = len(asked)
        for _ in range(frames):
            frame += 1
            watch.step(True, stale, explain)
        return np.diff(asked[start - 1 if start else 0:]).tolist()

    gaps = run(5000)
    window = chi2_watch.WINDOW
    assert gaps[: window - 1] == [EXPLAIN_EVERY] * (window - 1)
    assert gaps[window - 1: 2 * window - 1] == [2 * EXPLAIN_EVERY] * window
    assert max(gaps) == chi2_watch.EXPLAIN_EVERY_LONGEST == gaps[-1]
    assert len(asked) < 5000 / EXPLAIN_EVERY / 5  # ~115 looks in 5,000 frames instead of 1,000
    before = frame
    stale_gaps = run(50, stale=True)
    assert asked[-len(stale_gaps)] == before + 1  # the first stale frame is looked at at once
    assert set(stale_gaps[1:]) == {EXPLAIN_EVERY}  # and then closely again
    watch.step(False, False, explain)
    asked.clear()
    assert run(30) == [EXPLAIN_EVERY] * 5  # a new suspect run starts at the first cadence

"""Physical signatures of the photon-transfer sensor and of bad pixels."""

from __future__ import annotations

import numpy as np
import pytest

from .helpers import light, quiet_rig


def test_photon_transfer_variance_is_read_plus_shot_in_output_counts():
    """8-bit, 20 ke⁻ full well, 15 e⁻ read noise: var(DN) = (15·K)² + K·(DN − black) + 1/12, K = 255/20000."""
    rig = quiet_rig(effects=["photon_transfer:full_well=20000:read_e=15:bits=8:black_gray=4"], seed=1)
    frames = rig.render(np.full(4000, 2.0), np.zeros(4000)).astype(float)[:, 0]
    mean, var = frames.mean(axis=0), frames.var(axis=0)
    gain = 255.0 / 20000
    slope, intercept = np.polyfit(mean - 4.0, var, 1)
    assert slope == pytest.approx(gain, rel=0.1)
    assert intercept == pytest.approx((15 * gain) ** 2 + 1 / 12, abs=0.04)
    assert rig.frame_dtype == np.uint8
    assert mean.min() > 4.0  # the black level lifts the darkest pixel


def test_bad_pixels_stick_offset_or_add_noise_at_their_places_only_from_start_time():
    rig = quiet_rig(effects=["rows:n=4", "bad_pixels:stuck=1:dead=1:hot=1:noisy=1:hot_gray=40:noisy_gray=6:start_s=1"],
                    seed=3)
    bad = {(b.row, b.pixel): b for b in rig.config.sensor.bad_pixels}
    assert sorted(b.kind for b in bad.values()) == ["hot", "noisy", "stuck", "stuck"]
    x = np.full(300, 2.0)
    clean = light(rig, x[:1])[0]
    before = rig.render(x, np.zeros(300)).astype(float)
    after = rig.render(x, np.full(300, 1.5)).astype(float)
    np.testing.assert_allclose(before, np.broadcast_to(clean, before.shape), atol=1e-3)  # not bad yet
    good = np.ones(clean.shape, dtype=bool)
    for (r, u), b in bad.items():
        good[r, u] = False
        if b.kind == "stuck":
            assert np.all(after[:, r, u] == b.value)
        elif b.kind == "hot":
            np.testing.assert_allclose(after[:, r, u], clean[r, u] + 40.0, atol=1e-3)
        else:
            assert after[:, r, u].std() == pytest.approx(6.0, rel=0.15)
    np.testing.assert_allclose(after[:, good], np.broadcast_to(clean[good], (300, good.sum())), atol=1e-3)


def test_bad_pixels_given_a_place_sit_side_by_side_there():
    rig = quiet_rig(effects=["bad_pixels:stuck=1:dead=1:hot=1:row=0:pixel=10"])
    assert [(b.row, b.pixel, b.kind, b.value) for b in rig.config.sensor.bad_pixels] == [
        (0, 10, "stuck", 255.0), (0, 11, "stuck", 0.0), (0, 12, "hot", 40.0)]


def test_mjpeg_loses_detail_block_by_block_at_its_quality():
    """Baseline JPEG of each 8-bit frame: the loss sits in 8×8 blocks from the ROI's corner, grows as
    the quality falls, and quality 100 keeps the codes to within one step."""
    from graytrack.drivers.sim.jpeg import compress, quantisation_table
    from graytrack.drivers.sim.scenarios import build_rig

    plain, _ = build_rig("lab", seed=3).record(0.3)
    assert quantisation_table(50)[0, 0] == 16 and quantisation_table(75)[0, 0] == 8  # T.81 K.1, IJG scaling
    loss = {q: compress(plain.frames, q).astype(float) - plain.frames for q in (100, 75, 30)}
    assert np.abs(loss[100]).max() <= 1.0
    rms = {q: float(np.sqrt(np.mean(loss[q] ** 2))) for q in loss}
    assert rms[100] < 0.6 < rms[75] < rms[30]
    # block edges: the loss jumps more across a block's edge than inside it
    step = np.abs(np.diff(loss[30], axis=2)).mean(axis=(0, 1))
    assert step[7::8].mean() > 1.15 * np.delete(step, np.s_[7::8]).mean()
    rig = build_rig("lab", "mjpeg:quality=75", seed=3)
    recorded, _ = rig.record(0.3)
    assert recorded.frames.dtype == np.uint8 and rig.config.sensor.jpeg_quality == 75
    assert np.abs(recorded.frames.astype(float) - compress(plain.frames, 75)).max() == 0.0  # same frames, compressed

"""Signature of the virtual rig's ``glints`` effect: compact, short, bright blobs pinned to the print
(what tracking and calibration do with them: tests/core/test_transients.py)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from graytrack.drivers.sim.scenarios import build_rig
from tests.core.test_transients import RUN_S, _session


def test_glints_effect_is_a_compact_short_bright_blob_pinned_to_the_print():
    rec, touched = _session("strip16", "glints:p=0.15", 1, RUN_S)
    frames = touched.any(axis=(1, 2))
    assert 0.10 < frames.mean() < 0.20  # the share asked for, within the draw's spread
    plain, _ = build_rig("strip16", "", seed=3, run=1).record(RUN_S)
    added = rec.strip().astype(float) - plain.strip().astype(float)
    peaks = added.max(axis=(1, 2))[frames]
    assert peaks.max() <= 200.0 + 3.0 and np.median(peaks) > 80.0 - 3.0
    for k in np.flatnonzero(frames):
        labels, count = ndimage.label(added[k] > 5.0)
        for blob in ndimage.find_objects(labels):  # each a few pixels and rows, not the line
            assert blob[0].stop - blob[0].start <= 12 and blob[1].stop - blob[1].start <= 16
    # events last 1..4 frames (two may touch)
    edges = np.diff(np.concatenate(([0], frames.astype(int), [0])))
    lengths = np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)
    assert lengths.min() >= 1 and np.percentile(lengths, 90) <= 6


def test_a_glint_is_pinned_to_the_print_while_the_stage_moves():
    rec, touched = _session("paper", "glints:p=0.15", 1, RUN_S)
    plain, _ = build_rig("paper", "", seed=3, run=1).record(RUN_S)
    added = (rec.strip().astype(float) - plain.strip().astype(float))[:, 0]
    frames = touched.any(axis=(1, 2)).astype(int)
    edges = np.diff(np.concatenate(([0], frames, [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    u = np.arange(added.shape[1])
    checked = 0
    for a, b in zip(starts, stops):
        if b - a < 3:
            continue
        centre = (added[a:b] * u).sum(axis=1) / added[a:b].sum(axis=1)
        moved_px = (rec.reference[a:b] - rec.reference[a]) / rec.meta["pixel_pitch_mm"]
        if np.ptp(centre + moved_px) < 0.15:  # the pixel that sees the spot moves back as the stage moves on
            checked += 1
    assert checked >= 3


def test_glints_saturate_an_8_bit_sensor():
    rec, touched = _session("paper", "glints:p=0.15,quantize:bits=8", 1, RUN_S)
    frames = rec.strip()
    assert (frames[touched] == 255).any()


def test_glints_compose_the_later_spec_replaces_the_rate():
    rec, touched = _session("paper", "glints:p=0.05,glints:p=0.15", 1, RUN_S)
    assert 0.10 < touched.any(axis=(1, 2)).mean() < 0.20

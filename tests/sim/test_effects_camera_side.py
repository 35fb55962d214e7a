"""What changes on the camera's side during a run (drivers/sim/camera_side.py): dust landing on the
window, a veil, a changed vignetting. Their signature: fixed to the pixels whatever the stage does
(a mark on the print moves with it), there from their instant on and to the end; the specks landing
`at_rest` only on frames the stage stands still for; seeded; the live camera's one-frame render
gives the batch render's frames."""

from __future__ import annotations

import numpy as np
import pytest

from graytrack.drivers.sim.camera_side import REST_SPEED_MM_S
from graytrack.drivers.sim.effects import EffectError
from graytrack.drivers.sim.frame_render import FrameRenderer
from graytrack.drivers.sim.rig import Truth
from graytrack.drivers.sim.scenarios import build_rig, list_effects
from graytrack.drivers.sim.stage import steps

from .helpers import light, quiet_rig

ONE_SPECK = "window_dust:count=1:start_s=1:over_s=0:sigma_min_px=1.5:sigma_max_px=1.5:depth_min=0.4:depth_max=0.4"
VEIL = "veil:depth=0.25:scatter_gray=3:cover=0.4:side=1:edge_px=8:start_s=2:rise_s=0.5"


def _gain(rig_effects: list[str], x_mm: float, t_s: float, scenario: str = "clean") -> np.ndarray:
    """The light's gain on every pixel ``(R, n)``, stage still at ``x_mm`` at ``t_s``, against the rig without them."""
    return (light(quiet_rig(scenario, rig_effects), [x_mm], [t_s])[0]
            / light(quiet_rig(scenario), [x_mm], [t_s])[0])


def test_listed_with_their_parameters():
    effects = list_effects()
    assert "at_rest=0" in effects["window_dust"] and "sigma_min_px=1" in effects["window_dust"]
    assert "depth=0.25" in effects["veil"] and "scatter_gray=" in effects["veil"]
    assert "delta=0.05" in effects["vignetting_change"]


def test_a_window_speck_stays_on_its_pixel_while_a_print_speck_moves_with_the_stage():
    """Two frames 1.24 mm (20 pixel footprints) apart: the window's speck darkens the same pixels
    by the same share; a speck of dust on the print moves 20 pixels with the stage."""
    pitch = quiet_rig().pixel_pitch_mm
    window = [_gain([ONE_SPECK], x, 1.5) for x in (2.0, 2.0 + 20 * pitch)]
    np.testing.assert_allclose(window[0], window[1], rtol=1e-12)
    side = quiet_rig(effects=[ONE_SPECK]).camera_side
    assert side is not None
    row, pixel = side.centres[0]
    u = np.arange(100)
    np.testing.assert_allclose(window[0][0], 1 - 0.4 * np.exp(-(row ** 2 + (u - pixel) ** 2) / (2 * 1.5 ** 2)),
                               atol=1e-9)  # 40 % at its centre, its row within half a pixel of the line
    print_dust = "dust:count=1:size_um=90:depth=0.4"
    speck = quiet_rig(effects=[print_dust]).config.target.defects[0]
    x0 = speck.x_mm - 70 * pitch  # the speck seen on pixel 70, then on pixel 50
    places = [int(np.argmin(_gain([print_dust], x, 1.5)[0])) for x in (x0, x0 + 20 * pitch)]
    assert places[0] - places[1] == pytest.approx(20, abs=1)
    assert int(np.argmin(window[0][0])) == int(np.argmin(window[1][0]))


def test_a_speck_is_a_blob_over_rows_and_pixels_on_a_strip_from_its_instant_on():
    rig = quiet_rig("strip16", [ONE_SPECK])
    side = rig.camera_side
    assert side is not None
    row, pixel = side.centres[0]
    before, after, later = (_gain([ONE_SPECK], 3.0, t, "strip16") for t in (0.99, 1.0, 9.0))
    np.testing.assert_allclose(before, 1.0, atol=1e-15)
    np.testing.assert_allclose(after, later, rtol=1e-12)  # landed, it stays
    r, u = np.unravel_index(np.argmin(after), after.shape)
    assert abs(r - row) <= 0.5 and abs(u - pixel) <= 0.5
    # a Gaussian of σ 1.5 px both ways: the same share taken 2 rows or 2 pixels from the centre
    r0, u0 = int(round(row)), int(round(pixel))
    expected = 1 - 0.4 * np.exp(-((np.arange(16) - row) ** 2 + (u0 - pixel) ** 2) / (2 * 1.5 ** 2))
    np.testing.assert_allclose(after[:, u0], expected, rtol=1e-12)
    assert 1 - after[r0, u0 + 2 if u0 + 2 < 100 else u0 - 2] > 0.05


def test_specks_at_rest_land_only_while_the_stage_stands_still(tmp_path):
    """Step-and-settle over the stroke: every speck lands in a rest (the grating's stage not moving),
    at or after its own instant, and some wait for one; the frames before the first landing are those
    of the same rig without the dust, draw for draw, and after it they differ on the speck's pixels only."""
    spec = "window_dust:count=8:start_s=0.5:over_s=8:at_rest=1"
    rig = build_rig("strip16", [spec], seed=5)
    trajectory = steps(0.0, 10.0, 10, 0.4, rig.config.stage)
    run, truth = rig.record(10.0, trajectory)
    specks = truth.info["camera_side"]["window_specks"]
    assert truth.info["camera_side"]["at_rest"] and len(specks) == 8
    landed = np.array([s["landed_s"] for s in specks], dtype=float)
    begun = np.array([s["from_s"] for s in specks])
    assert np.all(np.isfinite(landed)) and np.all(landed >= begun)
    assert np.all(np.abs(trajectory.velocity(landed)) < REST_SPEED_MM_S)
    assert np.all(np.isin(landed, truth.t_s))  # on a frame's mid-exposure
    assert np.any(np.abs(trajectory.velocity(begun)) > 1.0)  # some came while it moved: they waited
    assert np.any(landed - begun > 0.05)
    plain, _ = build_rig("strip16", [], seed=5).record(10.0, steps(0.0, 10.0, 10, 0.4, rig.config.stage))
    first = truth.t_s < landed.min()
    assert first.sum() > 10 and np.array_equal(run.frames[first], plain.frames[first])
    last = specks[int(np.argmax(landed))]
    (r0, r1), (u0, u1) = last["rows"], last["pixels"]
    lost = 1 - run.frames[-1].astype(float) / plain.frames[-1]  # the same noise: the specks' share alone
    changed = lost > 0.01 * 0.5  # by more than the truth's 1 % of the deepest speck's depth
    assert changed[r0:r1 + 1, u0:u1 + 1].mean() > 0.5 and lost.max() > 0.15
    marked = np.zeros_like(changed)
    for speck in specks:
        (a, b), (c, d) = speck["rows"], speck["pixels"]
        marked[a:b + 1, c:d + 1] = True
    assert not changed[~marked].any()  # nothing beyond the pixels the truth names
    assert Truth.load(truth.save(tmp_path / "truth.npz")).info["camera_side"] == truth.info["camera_side"]


def test_specks_not_at_rest_land_at_their_own_instants_moving_or_not():
    rig = build_rig("paper", ["window_dust:count=8:start_s=0.5:over_s=8"], seed=5)
    trajectory = steps(0.0, 10.0, 10, 0.4, rig.config.stage)
    _, truth = rig.record(10.0, trajectory)
    specks = truth.info["camera_side"]["window_specks"]
    assert [s["landed_s"] for s in specks] == [s["from_s"] for s in specks]
    assert np.any(np.abs(trajectory.velocity(np.array([s["from_s"] for s in specks]))) > 1.0)


@pytest.mark.parametrize("scenario", ["clean", "strip16"])
def test_the_veil_darkens_and_scatters_where_it_covers_and_nowhere_else(scenario: str):
    def veiled(x_mm: float, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        return light(quiet_rig(scenario, [VEIL]), [x_mm], [t_s])[0], light(quiet_rig(scenario), [x_mm], [t_s])[0]

    for x in (2.0, 5.3):  # fixed to the pixels: the same wherever the stage is
        on, off = veiled(x, 1.99)
        np.testing.assert_array_equal(on, off)  # before it forms
        on, off = veiled(x, 2.6)
        # the last 40 of 100 pixels, edge 8 px wide about the boundary at 59.5: 0..55 clear, 64..99 covered
        np.testing.assert_array_equal(on[:, :56], off[:, :56])
        np.testing.assert_allclose(on[:, 64:], 0.75 * off[:, 64:] + 3.0, rtol=1e-12)
        edge = (off[:, 56:64] - on[:, 56:64]) / (0.25 * off[:, 56:64] - 3.0)  # the share of the veil there
        assert np.all(np.diff(edge, axis=1) > 0) and 0 < edge.min() and edge.max() < 1
        on, off = veiled(x, 2.25)  # halfway through forming
        np.testing.assert_allclose(on[:, 64:], 0.875 * off[:, 64:] + 1.5, rtol=1e-12)
    left = light(quiet_rig(scenario, [VEIL.replace("side=1", "side=0")]), [2.0], [3.0])[0]
    base = light(quiet_rig(scenario), [2.0], [3.0])[0]
    np.testing.assert_allclose(left[:, :36], 0.75 * base[:, :36] + 3.0, rtol=1e-12)
    np.testing.assert_array_equal(left[:, 44:], base[:, 44:])


def test_the_vignetting_change_reaches_delta_at_the_edge():
    """The paper rig's line spans its sensor: its end pixels sit at ρ² = 0.98 of the half-width."""
    spec = "vignetting_change:delta=0.08:start_s=2:ramp_s=1"
    rig = quiet_rig("paper", [spec])
    radius2 = rig.geometry.radius2[0]
    assert radius2[0] > 0.95 and radius2.min() < 1e-3
    for x in (1.0, 6.0):
        before, half, after = (_gain([spec], x, t, "paper")[0] for t in (1.9, 2.5, 3.5))
        np.testing.assert_allclose(before, 1.0, rtol=1e-14)
        np.testing.assert_allclose(half, 1 - 0.04 * radius2, rtol=1e-12)
        np.testing.assert_allclose(after, 1 - 0.08 * radius2, rtol=1e-12)
        assert 1 - after[0] == pytest.approx(0.08 * radius2[0]) and 1 - after.max() < 1e-4  # centre unchanged


EFFECTS = ["window_dust:count=12:start_s=0.1:over_s=1", "window_dust:count=12:start_s=0.1:over_s=1:at_rest=1",
           VEIL.replace("start_s=2", "start_s=0.5"), "vignetting_change:delta=0.1:start_s=0.3:ramp_s=0.5",
           "window_dust:count=5:start_s=0.2:over_s=1,veil:start_s=0.6,vignetting_change:start_s=0.4,flicker"]


@pytest.mark.parametrize("effect", EFFECTS)
def test_seeded_same_seed_same_frames(effect: str):
    records = [build_rig("strip16", [effect], seed=seed).record(1.5) for seed in (7, 7, 8)]
    (a, ta), (b, tb), (c, tc) = records
    assert np.array_equal(a.frames, b.frames) and ta.info == tb.info
    assert not np.array_equal(a.frames, c.frames)
    if "window_dust" in effect:
        assert ta.info["camera_side"]["window_specks"] != tc.info["camera_side"]["window_specks"]


@pytest.mark.parametrize("scenario", ["paper", "strip16"])
@pytest.mark.parametrize("effect", EFFECTS)
def test_the_live_cameras_frames_are_the_batch_renders(effect: str, scenario: str):
    """Frame by frame through the live camera's renderer, the rig's batch render: still and moving
    exposures in turn (the specks at rest land on the same frames), light to 1e-9 gray, frames to
    float32 rounding, the same landing instants."""
    direct, fast = build_rig(scenario, [effect], seed=3), build_rig(scenario, [effect], seed=3)
    renderer = FrameRenderer(fast)
    assert renderer.fallback is None  # fixed to the pixels: folded, no per-pixel path
    exposure = direct.exposure_s
    frames = 120
    t = 0.02 * np.arange(frames)
    moving = (np.arange(frames) // 10) % 2 == 1  # 10 frames still, 10 moving, ...
    x = np.array([2.0 + (0.05 * k if go else 0.0) + np.array([0.0, 0.0005, 0.001]) * go
                  for k, go in enumerate(moving)])
    want = direct.render(x, t)
    got = np.stack([renderer.render(x[k], float(t[k]), exposure) for k in range(frames)])
    assert np.max(np.abs(got.astype(np.float64) - want)) <= 1e-3
    np.testing.assert_array_equal(fast.camera_side.landed_s, direct.camera_side.landed_s)
    lights = (direct.render_light(x[:5], t[-5:]), np.concatenate([renderer.light(x[k], float(t[-5 + k]), exposure)
                                                                 for k in range(5)]))
    assert np.max(np.abs(lights[0] - lights[1])) <= 1e-9
    if "at_rest=1" in effect:
        landed = direct.camera_side.landed_s
        assert np.all(np.isfinite(landed)) and not np.any(moving[np.searchsorted(t, landed)])


def test_bad_parameters_are_refused():
    for spec in ("window_dust:at_rest=2", "window_dust:sigma_min_px=3:sigma_max_px=2", "window_dust:depth_max=1",
                 "window_dust:count=-1", "window_dust:sigma_min_px=0", "veil:depth=1", "veil:cover=1.5",
                 "veil:side=0.5", "veil:edge_px=-1", "vignetting_change:delta=1.2", "vignetting_change:ramp_s=-1",
                 "window_dust,window_dust:at_rest=1"):
        with pytest.raises(EffectError):
            quiet_rig(effects=[spec])

"""The estimator's state: what the rig does between frames, one entry a quantity.

Position and velocity of the stage; the light (a gain, an offset, and its shape across the line as
two Legendre terms, and a lamp's flicker at twice the mains); the focus (blur variance relative to
calibration); the magnification (a stretch about the optical axis, and the axis's lever from the
ROI's centre); the camera's place on the carriage (an offset along the axis, and its turn across
rows). Each belongs to the family a flag names when that state is what moved.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class StateEntry:
    name: str
    unit: str
    family: str  # the stale reason a flag carries when this state moved (core/validity.py FAMILIES)
    description: str


STATE: tuple[StateEntry, ...] = (
    StateEntry("x_mm", "mm", "geometry", "the stage (carriage) position"),
    StateEntry("v_mm_s", "mm/s", "geometry", "the stage velocity"),
    StateEntry("gain", "1", "light", "the light relative to calibration"),
    StateEntry("offset_gray", "gray", "light", "stray light added to every sample"),
    StateEntry("field_tilt", "1", "light", "the light's first Legendre term across the line (relative)"),
    StateEntry("field_bow", "1", "light", "the light's second Legendre term across the line (relative)"),
    StateEntry("focus_px2", "px²", "focus", "blur variance relative to calibration"),
    StateEntry("stretch", "1", "magnification", "magnification relative to calibration, minus one"),
    StateEntry("place_mm", "mm", "geometry", "the image's offset against the carriage (the camera's place)"),
    StateEntry("lever_mm", "mm", "magnification", "the optical axis's distance behind the ROI's centre"),
    StateEntry("turn_mm_row", "mm/row", "geometry", "the image's shift per row (the camera turned)"),
    StateEntry("skew_s", "s", "scale", "how much earlier than the exposure the grating was latched (with it fused)"),
    # a band of shadow or veil on the print's plane, fixed to neither the print nor the camera (a cable between the
    # lamp and the print, a lamp partly blocked): the light lost in its core, its two edges along the target from the
    # ROI's centre (an edge out of view: a veil over part of the field), their common speed across the field, the
    # softness of each edge (the penumbra) and the light it scatters under it; states only while a band is in view
    StateEntry("band_depth", "1", "light", "the light lost in the band's core (0: no band)"),
    StateEntry("band_left_mm", "mm", "light", "the band's left edge on the print's plane, from the ROI's centre"),
    StateEntry("band_right_mm", "mm", "light", "the band's right edge on the print's plane, from the ROI's centre"),
    StateEntry("band_speed_mm_s", "mm/s", "light", "the band's edges' speed across the field"),
    StateEntry("band_edge_mm", "mm", "light", "the softness of the band's edges (the penumbra's σ)"),
    StateEntry("band_haze_gray", "gray", "light", "the light the band scatters into what it covers (a veil's haze)"),
    # the camera's and the controller's clocks run at rates a few tens of ppm apart, steadily for hours: the latch
    # drifts at that rate (with the grating fused), a random walk alone lags behind it
    StateEntry("skew_rate_s_s", "s/s", "scale", "how fast the grating's latch drifts (the two clocks' rates apart)"),
    # a stage follows its commanded path within a servo's ripple and the floor's vibration: at one frame the carriage
    # is off the path by what no later frame inherits (white); the path itself bends only where it was commanded to
    StateEntry("jitter_mm", "mm", "geometry", "the carriage off its path at this frame (a servo's ripple, vibration)"),
    # a lens warming or cooling drifts its focus steadily over seconds to minutes: the blur drifts at that rate, which
    # itself changes slowly (a random walk of the blur alone lags behind a warming lens by most of what it drifted)
    StateEntry("focus_rate_px2_s", "px²/s", "focus", "how fast the blur variance drifts (a lens warming or cooling)"),
    # a lamp on the mains flickers at twice its frequency: the light a frame sees is the lamp's mean times that
    # flicker at the frame's time, which a camera faster than the flicker samples at a phase that walks from frame
    # to frame (at 200 frames/s, 100 Hz alternates; held at its mean, every frame's light was off by the flicker,
    # and over less than a period of the print the position with it). The gain is the frame's light; these two, the
    # flicker's parts in phase with the cosine and the sine of twice the mains at the frame's time, move it on from
    # frame to frame (kernel.predict) and are read only through it
    StateEntry("flicker_cos", "1", "light", "the lamp's flicker at twice the mains: its part with the cosine"),
    StateEntry("flicker_sin", "1", "light", "the lamp's flicker at twice the mains: its part with the sine"),
)
X, V, G, OFS, A1, A2, B, M, C, L, T, SK, BD, BL, BR, BW, BE, BH, SKR, D, FR, FC, FS = range(len(STATE))
FLICKER = (FC, FS)
BAND = (BD, BL, BR, BW, BE, BH)
# each state that drifts at a rate the state holds too (an integrated random walk: the rate's change white), with
# that rate's state: the grating's latch and the clocks' rates apart, the blur and a lens's warming
DRIFTS = ((SK, SKR), (B, FR))
# the states no sample and no reading sees: the carriage's jitter moves the path, not the image, a drift's rate
# shows only through the state it drifts, and the flicker only through the frame's light it moves. Each update
# solves the others; these are their prior conditioned on the solution (kernel.conditioned, kernel.embed), exactly
# what solving them with the others would give, a row and a column fewer in every solve.
UNREAD = (D, SKR, FR, FC, FS)
N_STATE = len(STATE)
FAMILIES = {entry.family for entry in STATE}

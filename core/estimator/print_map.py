"""What sits on the print, learned while tracking: a reflectance change at each place along the target.

Dust settling on the print, a smudge, a fibre: each changes the light of whatever sample sees that place
of the target, at whatever pixel, and moves past the camera with the stage. A sample's gray value is then
``(1 + f(u))·h`` of what the calibrated model predicts (h, through the estimator's state), u the target
coordinate the sample sees (the image's position plus the pixel's place on the target). ``f`` is held at
nodes a quarter of a pixel's footprint apart along each row of the model (a speck narrower than a pixel,
blurred by the optics and the pixel, keeps its shape), each node's value with its variance; a sample reads
its nearest node carried to its offset by the slope towards the next, and each node learns from the samples
nearest it alone. (Learning both nodes a sample lies between would tie it to two unknowns, and a filter per
node cannot see the difference of two neighbours that the samples' phases do not separate: they would drift
apart in opposite signs.)

- **Untouched** nodes are as calibrated (f = 0, known): the map costs a steady frame nothing.
- **Landing**: where a sample fails its test and neither map holds it (sensor_map.land), something landed
  on the sensor's side *or* on the print there: the sample is a candidate in both maps. The print's nodes
  within reach of the place it sees are touched, their variance the declared jump (``print_jump``).
- **The motion decides**: a node is used for the position only once the print has carried it across
  ``TRAVEL_PX`` pixels and what it predicts there has beaten what the sensor's side predicts (its own map's
  candidates, or the calibration) by one sample's test at the false-alarm rate: a mark on the sensor's side
  stays at its pixels, and the node, carried on, says a mark where there is none or another (its evidence
  falls below nought and it is let go). Until then the samples that see it wait outside the position, as
  the sensor's unresolved ones do; while the stage rests, neither map takes a mark on faith.
- **Learning**: each touched node is updated by every placed frame whose position is its own (the
  sensor map's ``teach``), from what the frame leaves at the samples that see it, and drifts at the
  declared rate (``print_rate``) between frames; one whose sample fails its test again jumps (more dust
  landed on it). Its evidence over the frames since its last jump (each one's predictive density against
  that of the sensor's side's account) lets it go where the frames speak for that account again (a glint
  gone, a mark on the window the print carried the node away from).

Each corrected sample's variance grows by the map's at its place and by the node's slope times the image
position's variance (a speck's edge is far steeper than the print's sine: read a micrometre off, it would
pull the frame harder than the print holds it).
"""

from __future__ import annotations

import math

import numpy as np

from typing import Any

from graytrack.core import kernels
from graytrack.core.estimator.marks import MarkShape, ToldMarks, figure, runs
from graytrack.core.estimator.sensor_map import BLOCKED, TRAVEL_PX  # (TRAVEL_PX: a node carried across it is used)

# numba keys its cache by this file's stamp alone, and compiles in the values this file's functions read from
# another: a change of them there, unstated here, left the compiled map with the old values. Stated here, a change
# there must change this file, and does:
COMPILED_FROM_SENSOR_MAP = {"BLOCKED": 0.05, "TRAVEL_PX": 1.0}
if COMPILED_FROM_SENSOR_MAP != {"BLOCKED": BLOCKED, "TRAVEL_PX": TRAVEL_PX}:
    raise ImportError("core/estimator/sensor_map.py's BLOCKED or TRAVEL_PX differ from print_map.py's "
                      "COMPILED_FROM_SENSOR_MAP: update it with them (they key the compiled print map's cache)")

NODES_PER_PIXEL = 4  # nodes a pixel's footprint on the target (module docstring: a speck keeps its shape)
REACH_PX = 1.0  # how far a mark landing on the print reaches beyond the samples that fail their test: the print
# is in focus, so a mark's edge below the test lies within a pixel of them (a mark on the window, out of focus,
# reaches further: the sensor map's map_reach_px)
MARGIN_MM = 1.0  # the map's reach beyond the stroke and the field at either end (a stage overshooting its stroke)


def locate(xi: float, stretch: float, target: np.ndarray, centred: np.ndarray, rows: np.ndarray, origin: float,
           step: float, nodes: int, k_out: np.ndarray, a_out: np.ndarray) -> None:
    """Each sample's nearest node to the target coordinate it sees (``xi`` the image's position, ``target`` the
    sample's place on the target, ``centred`` that place from the field's centre for the ``stretch``) into
    ``k_out`` (its row's first node counted; −1 outside the map) and the coordinate's offset from that node
    (nodes, within ±½) into ``a_out``."""
    for p in range(target.size):
        u = (xi + target[p] + stretch * centred[p] - origin) / step
        k = math.floor(u + 0.5)
        if k < 1 or k >= nodes - 1:
            k_out[p] = -1
            a_out[p] = 0.0
            continue
        k_out[p] = rows[p] * nodes + k
        a_out[p] = u - k


def _slope(f: np.ndarray, j: int, a: float) -> float:
    """The map's change a node along, on the side of the node the sample sees."""
    return f[j + 1] - f[j] if a >= 0.0 else f[j] - f[j - 1]


def apply(y: np.ndarray, mask: np.ndarray, k: np.ndarray, a: np.ndarray, touched: np.ndarray, f: np.ndarray,
          s: np.ndarray, lo: np.ndarray, hi: np.ndarray, evidence: np.ndarray, confirm: float, h: np.ndarray,
          noise: np.ndarray, slope_var: float, y_out: np.ndarray, mask_out: np.ndarray, fp_out: np.ndarray) -> int:
    """The frame seen through the map into ``y_out``, ``mask_out``: a sample that sees a touched node is
    ``y/(1 + f)``, f the nearest node's carried to the sample's offset from it by the slope towards the next,
    its weight that of the raw sample's noise at the last predicted ``h`` with the map's variance there added
    (the node's, and its slope's times ``slope_var``, the image position's variance over the node spacing
    squared), scaled by (1 + f)²; one that sees a node the motion has not yet decided waits outside the position (weight
    0). ``fp_out``: the f each sample was divided by (0 where none). Returns the samples that saw a touched
    node."""
    read_var, shot_gain, dark = noise[0], noise[1], noise[2]
    seen = 0
    for p in range(y.size):
        y_out[p] = y[p]
        mask_out[p] = mask[p]
        fp_out[p] = 0.0
        j = k[p]
        if j < 0 or not touched[j] or mask[p] <= 0.0:
            continue
        seen += 1
        if hi[j] - lo[j] < TRAVEL_PX or evidence[j] < confirm:
            mask_out[p] = 0.0  # a candidate the motion has not decided: it waits
            continue
        slope = _slope(f, j, a[p])
        fp = f[j] + slope * a[p]
        scale = 1.0 + fp
        if scale < BLOCKED:
            mask_out[p] = 0.0
            continue
        hp = h[p]
        model_signal = hp - dark
        raw_signal = scale * hp - dark
        var_model = read_var + shot_gain * (model_signal if model_signal > 0.0 else 0.0)
        var_raw = read_var + shot_gain * (raw_signal if raw_signal > 0.0 else 0.0)
        if mask[p] * hp * hp * s[j] > var_raw:
            mask_out[p] = 0.0  # the node known less well than the sample's noise: not yet learned
            continue
        y_out[p] = y[p] / scale
        fp_out[p] = fp
        var_map = hp * hp * (s[j] + slope * slope * slope_var)
        mask_out[p] = mask[p] * var_model * scale * scale / (var_raw + mask[p] * var_map)
    return seen


def learn(y: np.ndarray, h: np.ndarray, other: np.ndarray, other_var: np.ndarray, noise_var: np.ndarray,
          mask: np.ndarray, level: float,
          t: float, z2: float, params: np.ndarray, k: np.ndarray, a: np.ndarray, px: np.ndarray,
          touched: np.ndarray, f: np.ndarray, s: np.ndarray, evidence: np.ndarray, lo: np.ndarray, hi: np.ndarray,
          t_last: np.ndarray, teach: bool, vouched: bool, fp: np.ndarray, rival: np.ndarray,
          rival_var: np.ndarray) -> int:
    """One placed frame into the touched nodes it sees. ``y``: each sample as the print's side of the image
    gives it (the sensor's pair divided out where the sensor map uses it), ``h``: the model's value there (the
    posterior state's), ``other``: what the sensor's side says the sample is where the print is as
    calibrated (its pair's prediction where the sensor's map holds the sample as a candidate, else ``h``) and
    ``other_var`` that prediction's variance (its pair's; 0 where it is the model's),
    ``noise_var``: the noise model's variance, ``mask``: the raw frame's weights, ``level``: the calibration's
    χ² per sample, ``t``: the frame's time (s), ``z2``: the per-sample test (σ²), ``params``: the jump's
    variance and the rate's per second, ``px``: each sample's pixel along its row. Each node seen moves on by
    its rate since it was last seen; where its sample's residual fails its test it jumps first (more dust
    landed on it); the frame's evidence for the node over the sensor's side's account of the sample is added
    (at the pixel it landed at both tell the same, and the evidence stays near nought; carried to other
    pixels, a mark on the print is where the node says, one on the sensor's side where the sensor's map
    says), the node let go where it falls below nought; where ``teach``, the node is updated by the residual
    against it carried to the sample by its slope (its neighbour held: each node learns from the samples
    nearest it alone). ``vouched``: whether the frame's test vouches for its position: only then does where it sees
    a node count for the stretch of the row the print carried the node across. ``fp``: the f the frame was divided
    by at each sample (:func:`apply`). ``rival``,
    ``rival_var`` out: what the print's side says each sample is before the sensor's side, and that account's
    variance — the model's value times ``1 + fp`` where the map is used (variance 0: the model's), the node's
    prediction where it holds a candidate the motion has not decided (the node's variance) — against which the
    sensor's map weighs its own evidence, as this map weighs its against ``other``. Returns the nodes that
    jumped."""
    jump, rate = params[0], params[1]
    jumped = 0
    for p in range(y.size):
        j = k[p]
        rival[p] = (1.0 + fp[p]) * h[p]
        rival_var[p] = 0.0
        if j < 0 or mask[p] <= 0.0 or not touched[j]:
            continue
        if t_last[j] != t_last[j]:
            t_last[j] = t  # restored from another run: its drift is counted from this run's first frame to see it
        elif t > t_last[j]:
            s[j] += rate * (t - t_last[j])
            t_last[j] = t
        hp = h[p]
        var_y = noise_var[p] * level / mask[p]
        r = y[p] - (1.0 + f[j] + _slope(f, j, a[p]) * a[p]) * hp
        s_pred = hp * hp * s[j] + var_y
        if r * r > z2 * s_pred:
            # a change beyond what the node holds (more dust on it): its evidence starts again with this frame's
            evidence[j] = 0.0
            s[j] += jump
            s_pred = hp * hp * s[j] + var_y
            jumped += 1
        if fp[p] == 0.0:  # a candidate here, not used: its account is the print's rival to the sensor's pair
            rival[p] = y[p] - r
            rival_var[p] = hp * hp * s[j]
        if vouched:  # (where along the row a frame the test flagged placed the node says nothing of the motion)
            position = px[p] - a[p] / NODES_PER_PIXEL  # where along the row the node itself was seen
            if position < lo[j]:
                lo[j] = position
            if position > hi[j]:
                hi[j] = position
        r0 = y[p] - other[p]
        s0 = var_y + other_var[p]
        evidence[j] += 0.5 * (r0 * r0 / s0 - r * r / s_pred - math.log(s_pred / s0))
        if evidence[j] < 0.0:
            # the frames speak for the sensor's side's account here: a mark on the sensor's side the print carried
            # the node away from, a glint gone
            touched[j] = False
            f[j], s[j], evidence[j] = 0.0, 0.0, 0.0
            continue
        if teach:
            gain = hp * s[j] / s_pred
            f[j] += gain * r
            s[j] -= gain * gain * s_pred
            if hi[j] - lo[j] >= TRAVEL_PX and f[j] * f[j] <= s[j]:
                # carried across the pixels and within its own σ of nought: nothing there the frames can tell (a false
                # alarm's candidate, or a mark gone), as the print was calibrated
                touched[j] = False
                f[j], s[j], evidence[j] = 0.0, 0.0, 0.0
    return jumped


def land(core: np.ndarray, k: np.ndarray, a: np.ndarray, px: np.ndarray, reach: int, nodes: int, t: float,
         jump: float, touched: np.ndarray, f: np.ndarray, s: np.ndarray, evidence: np.ndarray, lo: np.ndarray,
         hi: np.ndarray, t_last: np.ndarray) -> int:
    """The nodes within ``reach`` of each sample in ``core`` (the samples that failed their test, held by
    neither map) touched: f 0 with the jump's variance, seen at that sample's pixel. Returns the nodes touched."""
    fresh = 0
    for p in range(core.size):
        if not core[p] or k[p] < 0:
            continue
        j = k[p]
        first = (j // nodes) * nodes
        start, stop = j - reach, j + reach + 1
        if start < first:
            start = first
        if stop > first + nodes:
            stop = first + nodes
        for q in range(start, stop):
            if touched[q]:
                continue
            touched[q] = True
            f[q], s[q], evidence[q], t_last[q] = 0.0, jump, 0.0, t
            position = px[p] + (q - j - a[p]) / NODES_PER_PIXEL  # where along the row the node was seen
            lo[q] = hi[q] = position
            fresh += 1
    return fresh


if kernels.COMPILED:
    _jit = kernels.numba.njit(cache=True, nogil=True, error_model="numpy")
    _slope = _jit(_slope)
    locate = _jit(locate)
    apply = _jit(apply)
    learn = _jit(learn)
    land = _jit(land)


class PrintMap(ToldMarks):
    """The map along the target of a model: ``rows`` rows of nodes ``step`` mm apart from ``origin`` (mm of
    target coordinate), each one's reflectance change and its variance, whether anything landed on it, its
    evidence and the pixels it was seen at. ``target``: each sample's place on the target (the model's
    target_offset, flattened), ``pixels``: samples a row; ``noise``, ``level``, ``z`` as the sensor map's;
    ``params``: the jump's and the rate's variances; ``reach``: nodes a landing touches either side;
    ``mean_gray``: the light's scale (a restored map's samples' predicted value until a frame says)."""

    # a mark: a run of neighbouring learned nodes along a row (marks.py tells them as they change)
    SHAPE = MarkShape("first_node", "last_node", ("row", "first_node", "last_node", "nodes", "from_mm", "to_mm",
                                                  "x_mm"), (("reflectance", "reflectance_sigma"),))

    def __init__(self, target: np.ndarray, rows: int, pixels: int, step: float, origin: float, span: float,
                 noise: np.ndarray, level: float, z: float, params: np.ndarray, reach: int,
                 mean_gray: float = 1.0) -> None:
        self.target = np.ascontiguousarray(target, dtype=np.float64)
        self.centred = np.ascontiguousarray(self.target - self.target.mean())
        self.row = int(pixels)
        self.rows_of = np.ascontiguousarray(np.repeat(np.arange(rows, dtype=np.int64), pixels))
        self.px = np.ascontiguousarray(np.tile(np.arange(pixels, dtype=np.float64), rows))
        # the grid from ``origin`` along the print's coordinates; a run placed from the image alone is a whole number
        # of periods off them (``shift``: the print's coordinate less the run's, print_origin.py), and the grid is
        # read at ``origin`` less it
        self.step, self.base_origin, self.shift = float(step), float(origin), 0.0
        self.origin = self.base_origin
        self.nodes = int(math.ceil(span / step)) + 2
        self.stride = self.nodes  # nodes a row
        self.mean_gray = float(mean_gray)
        self.noise, self.level, self.z2, self.params = noise, float(level), float(z) ** 2, params
        self.reach = int(reach)
        # a node is used once its evidence over the sensor's side's account is that of one sample's test at the
        # false-alarm rate (the likelihood ratio's log at z²/2)
        self.confirm = 0.5 * self.z2
        n = rows * self.nodes
        self.touched = np.zeros(n, dtype=np.bool_)
        self.f, self.s, self.evidence = np.zeros(n), np.zeros(n), np.zeros(n)
        self.lo, self.hi, self.t_last = np.zeros(n), np.zeros(n), np.zeros(n)
        n_values = self.target.size
        self.k, self.a = np.full(n_values, -1, dtype=np.int64), np.zeros(n_values)
        self.h = np.full(n_values, self.mean_gray)  # each sample's last predicted model value (apply weighs by it)
        self.fp = np.zeros(n_values)  # the f each sample of the last frame seen was divided by
        # what the print's side said each sample of the last frame learned from is, and that account's variance
        self.rival, self.rival_var = np.zeros(n_values), np.zeros(n_values)
        self.active = False
        self.jumps = 0
        self.landed = 0  # nodes touched as candidates, in all
        self.restored = np.zeros(n, dtype=np.bool_)  # learned before this run (restore)
        self._y, self._mask = np.empty(n_values), np.empty(n_values)

    @classmethod
    def of(cls, model, noise: np.ndarray, level: float, z: float, params: np.ndarray, mean_gray: float = 1.0,
           reach_px: float = REACH_PX) -> "PrintMap":
        """The map over the stroke of ``model`` and the field it sees, a margin beyond."""
        target = np.asarray(model.target_offset(), dtype=np.float64).reshape(-1)
        lo, hi = (float(v) for v in model.stroke_range_mm)
        stroke = model.info.get("stroke_mm")
        if stroke is not None and float(stroke[1]) > float(stroke[0]):
            lo, hi = min(lo, float(stroke[0])), max(hi, float(stroke[1]))
        origin = lo + float(target.min()) - MARGIN_MM
        span = hi + float(target.max()) + MARGIN_MM - origin
        step = model.pixel_pitch_mm / NODES_PER_PIXEL
        return cls(target, model.n_rows, model.n_pixels, step, origin, span, noise, level, z, params,
                   int(math.ceil(reach_px * NODES_PER_PIXEL)), mean_gray)

    def reset(self) -> None:
        self.restored = np.zeros(self.touched.size, dtype=np.bool_)  # learned before this run (restore)
        self.shift, self.origin = 0.0, self.base_origin
        self.touched[:] = False
        for array in (self.f, self.s, self.evidence, self.lo, self.hi, self.t_last):
            array[:] = 0.0
        self.fp[:] = 0.0
        self.h[:] = self.mean_gray  # (as the sensor map's reset: no frame before it weighs this run's samples)
        self.active = False
        self.jumps = 0
        self.landed = 0

    def reread(self, shift_mm: float) -> None:
        """Every node dropped, and the grid read ``shift_mm`` behind the print's coordinates from now on."""
        self.reset()
        self.shift, self.origin = float(shift_mm), self.base_origin - float(shift_mm)

    def seen(self, y: np.ndarray, mask: np.ndarray, xi: float, stretch: float,
             var_xi: float) -> tuple[np.ndarray, np.ndarray]:
        """The frame as the estimator updates with it, the image at ``xi`` ± √``var_xi`` mm stretched by
        ``stretch`` (the frame's own arrays where nothing landed)."""
        locate(xi, stretch, self.target, self.centred, self.rows_of, self.origin, self.step, self.nodes, self.k,
               self.a)
        apply(y, mask, self.k, self.a, self.touched, self.f, self.s, self.lo, self.hi, self.evidence, self.confirm,
              self.h, self.noise, var_xi / (self.step * self.step), self._y, self._mask, self.fp)
        return self._y, self._mask

    def land(self, core: np.ndarray, t: float, xi: float, stretch: float) -> int:
        """The nodes the samples ``core`` see with the image at ``xi`` touched: candidates."""
        locate(xi, stretch, self.target, self.centred, self.rows_of, self.origin, self.step, self.nodes, self.k,
               self.a)
        fresh = land(core, self.k, self.a, self.px, self.reach, self.nodes, t, self.params[0], self.touched,
                     self.f, self.s, self.evidence, self.lo, self.hi, self.t_last)
        if fresh:
            self.active = True
            self.landed += fresh
        return fresh

    def learn(self, y: np.ndarray, h: np.ndarray, other: np.ndarray, other_var: np.ndarray, noise_var: np.ndarray,
              mask: np.ndarray, t: float, teach: bool = True, vouched: bool = True) -> int:
        """The placed frame (located by the last :meth:`seen`) into the nodes it sees (:func:`learn`); ``rival``
        and ``rival_var`` then hold the print's side's account of each sample."""
        self.h[:] = h
        jumped = learn(y, h, other, other_var, noise_var, mask, self.level, t, self.z2, self.params, self.k, self.a,
                       self.px, self.touched, self.f, self.s, self.evidence, self.lo, self.hi, self.t_last, teach,
                       vouched, self.fp, self.rival, self.rival_var)
        self.jumps += jumped
        if not self.touched.any():
            self.active = False  # (every candidate let go: the map is the print as calibrated again, and costs nothing)
        return jumped

    def learned(self) -> np.ndarray:
        """The nodes the map holds a change for: carried across a pixel by the print and beyond zero at the
        per-sample test."""
        travelled = self.touched & (self.hi - self.lo >= TRAVEL_PX) & (self.evidence >= self.confirm)
        with np.errstate(divide="ignore", invalid="ignore"):
            beyond = self.f * self.f > self.z2 * self.s
        return travelled & beyond

    def keep_learned(self) -> None:
        """Every touched node the map has not learned let go (as calibrated): what a finished sweep left undecided is
        no mark to start a run from."""
        undecided = self.touched & ~self.learned()
        self.touched[undecided] = False
        for array in (self.f, self.s, self.evidence):
            array[undecided] = 0.0
        self.active = bool(self.touched.any())

    def describe(self) -> dict[str, object]:
        learned = np.flatnonzero(self.learned())
        return {"touched_nodes": int(self.touched.sum()), "learned_nodes": int(learned.size),
                "landed_nodes": self.landed, "jumps": self.jumps,
                "node_mm": self.step}

    def place_mm(self, nodes: np.ndarray) -> np.ndarray:
        """The print's coordinate (mm) of each of ``nodes`` (flat indices)."""
        return self.base_origin + (np.asarray(nodes) % self.nodes) * self.step

    # ------------------------------------------------------------------ kept between runs, told as it changes
    # (what the daemon keeps with its model of record, service/daemon/map_store.py, and says in its event log)

    def state(self) -> dict[str, Any]:
        """The map as a JSON document (:meth:`restore` reads it back): its grid, the touched nodes' reflectance
        change with its variance, evidence and the stretch of the row each was seen across, which of them are
        learned, and the marks those make. Untouched nodes are as calibrated and are not written."""
        where = np.flatnonzero(self.touched)
        learned = self.learned()
        return {"version": MAP_STATE_VERSION, "rows": self.touched.size // self.nodes, "nodes": self.nodes,
                "node_mm": self.step, "origin_mm": self.base_origin, "shift_mm": self.shift, "jumps": int(self.jumps),
                "landed": int(self.landed),
                "touched": where.tolist(), **{name: getattr(self, name)[where].tolist() for name in NODE},
                "learned": learned[where].tolist(), "marks": self.marks(learned)}

    def restore(self, state: dict[str, Any], shift_mm: float | None = None) -> None:
        """The map as ``state`` (:meth:`state`) holds it, read ``shift_mm`` behind the print's coordinates (the
        state's own shift where None); ValueError (one line) when it is not one this map can
        hold: another grid, a bad shape, a value that is not finite or a variance below nought. Nothing changes
        then. Each restored node's drift counts from the first frame of this run that sees it; the restored marks
        are what the next look compares against (not told again)."""
        try:
            if state.get("version") != MAP_STATE_VERSION:
                raise ValueError(f"version {state.get('version')!r}, not {MAP_STATE_VERSION}")
            grid = (int(state["rows"]), int(state["nodes"]), float(state["node_mm"]), float(state["origin_mm"]))
            where = np.asarray(state["touched"], dtype=np.int64).reshape(-1)
            values = {name: np.asarray(state[name], dtype=np.float64) for name in NODE}
            jumps, landed = int(state.get("jumps", 0)), int(state.get("landed", 0))
            shift = float(state.get("shift_mm", 0.0) if shift_mm is None else shift_mm)
        except (KeyError, TypeError, AttributeError) as exc:
            raise ValueError(f"not a print map state ({type(exc).__name__}: {exc})") from None
        rows = self.touched.size // self.nodes
        if grid[:2] != (rows, self.nodes) or not all(math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)
                                                      for a, b in zip(grid[2:], (self.step, self.base_origin))):
            raise ValueError(f"a grid of {grid[0]} row(s) of {grid[1]} nodes {grid[2]:.6g} mm apart from "
                             f"{grid[3]:.6g} mm, the map's is {rows} of {self.nodes} {self.step:.6g} mm apart from "
                             f"{self.base_origin:.6g} mm")
        if any(array.shape != where.shape for array in values.values()):
            raise ValueError(f"{where.size} touched nodes but the nodes' arrays have lengths "
                             f"{sorted({array.size for array in values.values()})}")
        if where.size and (where.min() < 0 or where.max() >= self.touched.size or np.unique(where).size != where.size):
            raise ValueError(f"touched nodes must be distinct and within 0..{self.touched.size - 1}")
        if not all(np.all(np.isfinite(array)) for array in values.values()) or not math.isfinite(shift):
            raise ValueError("a reflectance change, variance, evidence or stretch seen that is not finite")
        if np.any(values["s"] < 0.0) or np.any(values["hi"] < values["lo"]):
            raise ValueError("a variance below nought or a stretch seen that ends before it starts")
        self.reset()
        self.shift, self.origin = shift, self.base_origin - shift
        self.touched[where] = True
        for name, array in values.items():
            getattr(self, name)[where] = array
        self.t_last[where] = math.nan
        self.h[:] = self.mean_gray
        # what the last run had not decided starts again as a candidate just landed (as the sensor map's,
        # sensor_map.py restore: kept, one would be decided at its first deviation on the last run's travel and
        # evidence)
        undecided = where[~self.learned()[where]]
        self.f[undecided], self.s[undecided], self.evidence[undecided] = 0.0, self.params[0], 0.0
        self.hi[undecided] = self.lo[undecided]
        self.active = bool(where.size)
        self.jumps, self.landed = max(jumps, 0), max(landed, 0)
        self.restored = self.learned()
        self.restore_told()

    def marks(self, learned: np.ndarray | None = None) -> list[dict[str, Any]]:
        """The learned nodes (:meth:`learned`) as marks: each run of neighbouring learned nodes along a row, with
        the stretch of the target it covers (mm), its centre weighted by the light it changes, its mean reflectance
        ``1 + f`` (0.7: 30 % darker than calibrated) and a node's σ (the RMS over the mark's)."""
        learned = self.learned() if learned is None else learned
        found = []
        for start, stop in runs(learned, self.nodes):
            span = slice(start, stop)
            places = self.place_mm(np.arange(start, stop))
            weight = np.abs(self.f[span])
            centre = float(np.dot(weight, places) / weight.sum()) if weight.sum() > 0.0 else float(places.mean())
            found.append({"row": start // self.nodes, "first_node": start % self.nodes,
                          "last_node": (stop - 1) % self.nodes, "nodes": stop - start,
                          "from_mm": round(float(places[0]), 4), "to_mm": round(float(places[-1]), 4),
                          "x_mm": round(centre, 4), "reflectance": figure(1.0 + float(self.f[span].mean())),
                          "reflectance_sigma": figure(math.sqrt(float(self.s[span].mean())))})
        return found


MAP_STATE_VERSION = 1  # of :meth:`PrintMap.state`'s document
NODE = ("f", "s", "evidence", "lo", "hi")  # a touched node's arrays, as the state document names them


__all__ = ["PrintMap", "apply", "land", "learn", "locate"]

// Drawing for the status page: canvases at the device pixel ratio, axes with units, robust scales.
// No libraries (the rig may be offline). Exposes one global, `Plot`.
"use strict";

const Plot = (() => {
  const FONT = "12px system-ui, sans-serif";
  const UNIT_GAP = 9; // px between an axis's unit and its box: half a label's height (6 px) and a margin
  const UNIT_ROOM = 26; // px above a box for its unit: the gap and a label's height (12 px) and a margin

  // Size the canvas backing store to its CSS box × devicePixelRatio; draw in CSS pixels.
  function crisp(canvas) {
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(canvas.clientWidth));
    const height = Math.max(1, Math.round(canvas.clientHeight));
    if (canvas.width !== Math.round(width * ratio) || canvas.height !== Math.round(height * ratio)) {
      canvas.width = Math.round(width * ratio);
      canvas.height = Math.round(height * ratio);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
    ctx.clearRect(0, 0, width, height);
    ctx.font = FONT;
    canvas.labels = []; // every text drawn, with its box: tests/web check that none overlaps another
    return { ctx, width, height };
  }

  // Text at (x, y) with the context's alignment, its box (CSS px) kept on the canvas.
  function label(ctx, text, x, y) {
    const m = ctx.measureText(text);
    ctx.fillText(text, x, y);
    ctx.canvas.labels.push({ text, left: x - m.actualBoundingBoxLeft, right: x + m.actualBoundingBoxRight,
                             top: y - m.actualBoundingBoxAscent, bottom: y + m.actualBoundingBoxDescent });
  }

  function quantile(sorted, q) {
    if (!sorted.length) return NaN;
    const i = (sorted.length - 1) * q, lo = Math.floor(i), hi = Math.ceil(i);
    return sorted[lo] + (sorted[hi] - sorted[lo]) * (i - lo);
  }

  // A range that holds the bulk of the values: 1st–99th percentile widened by a margin, so one spike
  // does not flatten the trace; values outside are drawn at the edge and marked as clipped.
  function robustRange(values, minSpan) {
    const finite = values.filter(Number.isFinite).sort((a, b) => a - b);
    if (!finite.length) return null;
    let lo = quantile(finite, 0.01), hi = quantile(finite, 0.99);
    const margin = Math.max((hi - lo) * 0.15, minSpan / 2);
    lo -= margin; hi += margin;
    return [lo, hi];
  }

  // "Nice" tick values (1, 2, 5 × 10^k) over [lo, hi]: about `count`, never fewer than three.
  function ticks(lo, hi, count) {
    const span = hi - lo;
    if (!(span > 0)) return [lo];
    const power = Math.pow(10, Math.floor(Math.log10(span / count)));
    const steps = [10, 5, 2, 1, 0.5, 0.2, 0.1].map((m) => m * power).filter((s) => s <= span);
    let out = [];
    for (const step of steps) {
      if (span / step > 2 * count) break;
      out = [];
      for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
      if (out.length >= Math.min(3, count)) break;
    }
    return out.length ? out : [lo, hi];
  }

  function decimals(step) {
    return Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
  }

  function yAxis(ctx, box, range, unit, color, right) {
    const marks = ticks(range[0], range[1], 4);
    const digits = decimals(marks.length > 1 ? marks[1] - marks[0] : range[1] - range[0]);
    ctx.fillStyle = color;
    ctx.textAlign = right ? "left" : "right";
    ctx.textBaseline = "middle";
    for (const v of marks) {
      const y = box.bottom - (box.bottom - box.top) * (v - range[0]) / (range[1] - range[0]);
      ctx.strokeStyle = "#e2e5ea";
      ctx.beginPath(); ctx.moveTo(box.left, y); ctx.lineTo(box.right, y); ctx.stroke();
      label(ctx, v.toFixed(digits), right ? box.right + 4 : box.left - 4, y);
    }
    // the unit above the axis, clear of the top tick's label (centred on the box's top edge at most)
    ctx.textBaseline = "bottom";
    label(ctx, unit, right ? box.right + 4 : box.left - 4, box.top - UNIT_GAP);
  }

  // One trace; returns how many points were clipped (drawn as marks at the edge).
  function trace(ctx, box, xs, ys, xRange, yRange, color) {
    let clipped = 0, started = false;
    ctx.strokeStyle = color;
    ctx.lineWidth = 1.5;
    ctx.beginPath();
    const marks = [];
    for (let i = 0; i < xs.length; i++) {
      const y = ys[i];
      if (!Number.isFinite(y)) { started = false; continue; }
      const px = box.left + (box.right - box.left) * (xs[i] - xRange[0]) / (xRange[1] - xRange[0]);
      let py = box.bottom - (box.bottom - box.top) * (y - yRange[0]) / (yRange[1] - yRange[0]);
      if (py < box.top || py > box.bottom) {
        py = Math.min(Math.max(py, box.top), box.bottom);
        marks.push([px, py]);
        clipped++;
      }
      if (started) ctx.lineTo(px, py); else ctx.moveTo(px, py);
      started = true;
    }
    ctx.stroke();
    ctx.fillStyle = "#c53030";
    for (const [px, py] of marks) ctx.fillRect(px - 2, py - 2, 4, 4);
    return clipped;
  }

  // A filled band between lo[i] and hi[i] over n columns of the box (a σ band along the pixels).
  function band(ctx, box, lo, hi, yRange, color) {
    const n = lo.length;
    const px = (i) => box.left + (box.right - box.left) * (i + 0.5) / n;
    const y = (v) => box.bottom - (box.bottom - box.top) * (Math.min(Math.max(v, yRange[0]), yRange[1]) - yRange[0]) /
      (yRange[1] - yRange[0]);
    ctx.fillStyle = color;
    ctx.beginPath();
    hi.forEach((v, i) => { if (i) ctx.lineTo(px(i), y(v)); else ctx.moveTo(px(i), y(v)); });
    for (let i = n - 1; i >= 0; i--) ctx.lineTo(px(i), y(lo[i]));
    ctx.closePath(); ctx.fill();
  }

  // The pixel axis under a box: "pixel" at the right, ticks that do not run into it.
  function pixelAxis(ctx, left, right, n, y) {
    ctx.fillStyle = "#6b7380"; ctx.textBaseline = "top";
    ctx.textAlign = "right";
    label(ctx, "pixel", right, y);
    const unitLeft = ctx.canvas.labels[ctx.canvas.labels.length - 1].left;
    ctx.textAlign = "center";
    for (const i of ticks(0, n - 1, 6)) {
      const px = left + (right - left) * (i + 0.5) / n;
      // a tick whose number would run into "pixel" (a narrow screen) is left out
      if (px + ctx.measureText(String(i)).width / 2 + 4 < unitLeft) label(ctx, String(i), px, y);
    }
  }

  // A sentence in the middle of a box: what is (not) there to draw.
  function note(ctx, box, text) {
    ctx.fillStyle = "#6b7380"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
    label(ctx, text, (box.left + box.right) / 2, (box.top + box.bottom) / 2);
  }

  // Position (upper band) and error (lower band) against time, "now" at the right edge.
  function timeSeries(canvas, samples, now, windowS) {
    const { ctx, width, height } = crisp(canvas);
    const left = 62, right = width - 62, split = Math.round(height * 0.52);
    const xRange = [now - windowS, now];
    const visible = samples.filter((s) => s.t >= xRange[0]);
    const ts = visible.map((s) => s.t);
    const bands = [
      { key: "x", unit: "mm", color: "#2b6cb0", box: { left, right, top: UNIT_ROOM, bottom: split - 10 }, min: 1e-3, right: false },
      { key: "e", unit: "µm", color: "#b7791f", box: { left, right, top: split + UNIT_ROOM, bottom: height - 26 }, min: 1, right: true },
    ];
    let clipped = 0;
    for (const band of bands) {
      const ys = visible.map((s) => s[band.key]);
      const range = robustRange(ys, band.min);
      if (!range) continue;
      yAxis(ctx, band.box, range, band.unit, band.color, band.right);
      clipped += trace(ctx, band.box, ts, ys, xRange, range, band.color);
    }
    // time axis: seconds before now
    ctx.fillStyle = "#6b7380"; ctx.textAlign = "center"; ctx.textBaseline = "top";
    for (const ago of ticks(0, windowS, 5)) {
      const px = right - (right - left) * ago / windowS;
      label(ctx, ago === 0 ? "now" : `−${ago} s`, px, height - 20);
    }
    return clipped;
  }

  // The pixel line: frame and model above, residual with its ±σ band below; saturated and bad pixels marked.
  function profile(canvas, doc) {
    const { ctx, width, height } = crisp(canvas);
    const left = 52, right = width - 12, split = Math.round(height * 0.62);
    const n = doc.pixels.length;
    const xs = doc.pixels.map((_, i) => i);
    const xRange = [-0.5, n - 0.5];
    const top = { left, right, top: UNIT_ROOM, bottom: split - 8 };
    const bottom = { left, right, top: split + UNIT_ROOM, bottom: height - 22 };
    const grays = doc.pixels.concat(doc.model || []).filter(Number.isFinite);
    const grayRange = [Math.min(...grays), Math.max(...grays)];
    const pad = Math.max((grayRange[1] - grayRange[0]) * 0.08, 1);
    const gRange = [grayRange[0] - pad, grayRange[1] + pad];
    yAxis(ctx, top, gRange, "gray", "#2d3748", false);
    const column = (i, box, color) => {
      const px = box.left + (box.right - box.left) * (i + 0.5) / n;
      ctx.fillStyle = color;
      ctx.fillRect(px - 1.5, box.top, 3, box.bottom - box.top);
    };
    for (const i of doc.bad || []) column(i, top, "rgba(214,158,46,.35)");
    for (const i of doc.saturated || []) column(i, top, "rgba(229,62,62,.35)");
    trace(ctx, top, xs, doc.pixels, xRange, gRange, "#2d3748");
    if (doc.model) trace(ctx, top, xs, doc.model, xRange, gRange, "#2b6cb0");
    if (doc.residual && doc.sigma) {
      const limit = Math.max(3 * Math.max(...doc.sigma.filter(Number.isFinite)),
                             ...doc.residual.filter(Number.isFinite).map(Math.abs), 0.5);
      const rRange = [-limit * 1.1, limit * 1.1];
      band(ctx, bottom, doc.sigma.map((s) => -s), doc.sigma, rRange, "#cbd5e0");
      yAxis(ctx, bottom, rRange, "residual", "#4a5568", false);
      trace(ctx, bottom, xs, doc.residual, xRange, rRange, "#4a5568");
    }
    pixelAxis(ctx, left, right, n, height - 18);
  }

  // The sensor's map along the pixels (GET /api/maps): each pixel's gain (1: as calibrated) above and offset
  // (gray) below, each with its ±σ band; pixels something landed on and the motion has not yet resolved are
  // shaded. `doc` null: the engine keeps no sensor map (said, nothing drawn as if it were one).
  function sensorMap(canvas, doc) {
    const { ctx, width, height } = crisp(canvas);
    const left = 52, right = width - 12, split = Math.round(height * 0.55);
    const top = { left, right, top: UNIT_ROOM, bottom: split - 8 };
    const bottom = { left, right, top: split + UNIT_ROOM, bottom: height - 22 };
    if (!doc) {
      note(ctx, { left, right, top: 0, bottom: height }, "no sensor map: this engine keeps none");
      return;
    }
    const n = doc.pixels;
    const xs = doc.gain.map((_, i) => i);
    const xRange = [-0.5, n - 0.5];
    const learned = new Set(doc.learned), touched = new Set(doc.touched);
    for (const i of touched) {
      if (learned.has(i)) continue;
      const px = left + (right - left) * (i + 0.5) / n;
      ctx.fillStyle = "rgba(214,158,46,.25)";
      ctx.fillRect(px - (right - left) / n / 2, top.top, (right - left) / n, bottom.bottom - top.top);
    }
    const span = (values, sigmas, sign) => values.map((v, i) => v + sign * sigmas[i]);
    const gLo = span(doc.gain, doc.gain_sigma, -1), gHi = span(doc.gain, doc.gain_sigma, 1);
    const oLo = span(doc.offset_gray, doc.offset_sigma_gray, -1), oHi = span(doc.offset_gray, doc.offset_sigma_gray, 1);
    // resolved values set the scale (an unresolved sample's σ is its jump's width: drawn clipped at the edge)
    const shown = (values, sigmas) => values.filter((v, i) => !touched.has(i) || learned.has(i))
      .concat(doc.learned.map((i) => values[i] - sigmas[i]), doc.learned.map((i) => values[i] + sigmas[i]));
    const gains = shown(doc.gain, doc.gain_sigma);
    const gRange = [Math.min(...gains, 0.9) - 0.02, Math.max(...gains, 1.02) + 0.02];
    const offsets = shown(doc.offset_gray, doc.offset_sigma_gray).map(Math.abs);
    const oLimit = Math.max(...offsets, 1) * 1.1;
    const oRange = [-oLimit, oLimit];
    band(ctx, top, gLo, gHi, gRange, "rgba(43,108,176,.25)");
    yAxis(ctx, top, gRange, "gain", "#2b6cb0", false);
    trace(ctx, top, xs, doc.gain, xRange, gRange, "#2b6cb0");
    band(ctx, bottom, oLo, oHi, oRange, "rgba(183,121,31,.25)");
    yAxis(ctx, bottom, oRange, "offset", "#b7791f", false);  // in gray (the legend says)
    trace(ctx, bottom, xs, doc.offset_gray, xRange, oRange, "#b7791f");
    if (!doc.learned.length) {
      note(ctx, top, touched.size ? `${touched.size} px set aside, not yet resolved` : "nothing learned: as calibrated");
    }
    pixelAxis(ctx, left, right, n, height - 18);
  }

  // The print's texture along the target (GET /api/maps): each learned mark's stretch of the stroke with its
  // depth (the light it takes) and ±σ. `doc` null: the engine keeps no print texture.
  function textureMap(canvas, doc, stroke) {
    const frame = alongTarget(canvas, doc, stroke, "no print texture: this engine keeps none");
    if (!frame) return;
    const { ctx, height, left, right, box } = frame;
    const marks = doc.marks;
    const deepest = Math.max(0.1, ...marks.map((m) => Math.abs(m.depth) + (m.depth_sigma || 0)));
    const range = [0, Math.min(1, deepest * 1.15)];
    yAxis(ctx, box, range, "depth", "#2d3748", false);
    const x = (mm) => left + (right - left) * (mm - stroke[0]) / (stroke[1] - stroke[0]);
    const y = (v) => box.bottom - (box.bottom - box.top) * (Math.min(Math.max(v, range[0]), range[1]) - range[0]) /
      (range[1] - range[0]);
    for (const m of marks) {
      const x0 = x(m.from_mm), x1 = Math.max(x(m.to_mm), x0 + 2);
      ctx.fillStyle = "rgba(43,108,176,.55)";
      ctx.fillRect(x0, y(m.depth), x1 - x0, box.bottom - y(m.depth));
      if (m.depth_sigma !== null) {  // ±σ as a whisker at the mark's centre
        const xc = x(m.x_mm);
        ctx.strokeStyle = "#1a365d"; ctx.lineWidth = 1.5;
        ctx.beginPath(); ctx.moveTo(xc, y(m.depth - m.depth_sigma)); ctx.lineTo(xc, y(m.depth + m.depth_sigma)); ctx.stroke();
      }
    }
    if (!marks.length) note(ctx, box, "nothing learned: as calibrated");
    targetAxis(ctx, x, right, stroke, height - 18);
  }

  // A map's canvas along the target, cleared: its plot box, or null when there is nothing to draw (said: `absent`
  // when the engine keeps no such map, or that there is no model's stroke to draw it along).
  function alongTarget(canvas, doc, stroke, absent) {
    const { ctx, width, height } = crisp(canvas);
    const left = 52, right = width - 12;
    if (!doc || !stroke) {
      note(ctx, { left, right, top: 0, bottom: height }, doc ? "no model: no stroke to draw the print along" : absent);
      return null;
    }
    return { ctx, height, left, right, box: { left, right, top: UNIT_ROOM, bottom: height - 22 } };
  }

  // The axis along the target (x_w, mm) under a map drawn along it: `x` maps mm to the canvas, `range` its ends.
  function targetAxis(ctx, x, right, range, y) {
    ctx.fillStyle = "#6b7380"; ctx.textBaseline = "top"; ctx.textAlign = "right";
    label(ctx, "x_w (mm)", right, y);
    const unitLeft = ctx.canvas.labels[ctx.canvas.labels.length - 1].left;
    ctx.textAlign = "center";
    for (const mm of ticks(range[0], range[1], 6)) {
      const px = x(mm);
      if (px + 20 < unitLeft) label(ctx, String(Math.round(mm * 1000) / 1000), px, y);
    }
  }

  // The print's map along the target (GET /api/maps): each place something landed on, its reflectance (1: as
  // calibrated) as a bar from 1 with its ±σ whisker; places the motion has not yet decided (a candidate that may
  // as well sit on the sensor's side) shaded. `doc` null: the engine keeps no print map.
  function printMap(canvas, doc, stroke) {
    const frame = alongTarget(canvas, doc, stroke, "no print map: this engine keeps none");
    if (!frame) return;
    const { ctx, height, left, right, box } = frame;
    const xs = doc.x_mm, r = doc.reflectance, sigma = doc.reflectance_sigma;
    const range = [Math.min(stroke[0], ...xs), Math.max(stroke[1], ...xs)];
    const decided = xs.map((_, i) => i).filter((i) => doc.learned[i]);
    // resolved places set the scale (a candidate's σ is its jump's width)
    const ends = decided.flatMap((i) => [r[i] - sigma[i], r[i] + sigma[i]]);
    const rRange = [Math.min(0.9, ...ends) - 0.02, Math.max(1.02, ...ends) + 0.02];
    const x = (mm) => left + (right - left) * (mm - range[0]) / (range[1] - range[0]);
    const y = (v) => box.bottom - (box.bottom - box.top) * (Math.min(Math.max(v, rRange[0]), rRange[1]) - rRange[0]) /
      (rRange[1] - rRange[0]);
    ctx.fillStyle = "rgba(214,158,46,.35)";
    for (let i = 0; i < xs.length; i++) if (!doc.learned[i]) ctx.fillRect(x(xs[i]) - 1, box.top, 2, box.bottom - box.top);
    ctx.strokeStyle = "#a0aec0"; ctx.lineWidth = 1;  // as calibrated
    ctx.beginPath(); ctx.moveTo(left, y(1)); ctx.lineTo(right, y(1)); ctx.stroke();
    for (const i of decided) {
      const px = x(xs[i]);
      ctx.fillStyle = "rgba(43,108,176,.55)";
      ctx.fillRect(px - 1, Math.min(y(1), y(r[i])), 2, Math.max(Math.abs(y(r[i]) - y(1)), 1));
      ctx.strokeStyle = "#1a365d"; ctx.lineWidth = 1;  // ±σ
      ctx.beginPath(); ctx.moveTo(px, y(r[i] - sigma[i])); ctx.lineTo(px, y(r[i] + sigma[i])); ctx.stroke();
    }
    yAxis(ctx, box, rRange, "", "#2b6cb0", false);  // (its unit drawn below)
    ctx.textAlign = "left"; ctx.textBaseline = "bottom";  // the unit over the plot: wider than the tick labels' room
    label(ctx, "reflectance", left, box.top - UNIT_GAP);
    if (!decided.length) {
      note(ctx, box, xs.length ? `${xs.length} place(s) set aside, not yet decided` : "nothing learned: as calibrated");
    }
    targetAxis(ctx, x, right, range, height - 18);
  }

  return { timeSeries, profile, sensorMap, textureMap, printMap, robustRange, ticks };
})();

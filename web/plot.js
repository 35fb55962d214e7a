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
      const y = (v) => bottom.bottom - (bottom.bottom - bottom.top) * (v - rRange[0]) / (rRange[1] - rRange[0]);
      ctx.fillStyle = "#cbd5e0";
      ctx.beginPath();
      doc.sigma.forEach((s, i) => { const px = left + (right - left) * (i + 0.5) / n; if (i) ctx.lineTo(px, y(s)); else ctx.moveTo(px, y(s)); });
      for (let i = n - 1; i >= 0; i--) ctx.lineTo(left + (right - left) * (i + 0.5) / n, y(-doc.sigma[i]));
      ctx.closePath(); ctx.fill();
      yAxis(ctx, bottom, rRange, "residual", "#4a5568", false);
      trace(ctx, bottom, xs, doc.residual, xRange, rRange, "#4a5568");
    }
    ctx.fillStyle = "#6b7380"; ctx.textAlign = "center"; ctx.textBaseline = "top";
    ctx.textAlign = "right";
    label(ctx, "pixel", right, height - 18);
    const unitLeft = ctx.canvas.labels[ctx.canvas.labels.length - 1].left;
    ctx.textAlign = "center";
    for (const i of ticks(0, n - 1, 6)) {
      const px = left + (right - left) * (i + 0.5) / n;
      // a tick whose number would run into "pixel" (a narrow screen) is left out
      if (px + ctx.measureText(String(i)).width / 2 + 4 < unitLeft) label(ctx, String(i), px, height - 18);
    }
  }

  return { timeSeries, profile, robustRange, ticks };
})();

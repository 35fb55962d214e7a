// The status page: live position over /ws/position, state and calibration from /api/status,
// calibrate / move / stop with the bearer token kept in localStorage. No libraries: the rig may be offline.
"use strict";

const TOKEN_KEY = "graytrack.token";
const PLOT_SECONDS = 10;
const $ = (id) => document.getElementById(id);
const samples = []; // {t (s, page clock), x (mm), e (µm or null)}
let latest = null; // newest WebSocket message, drawn on the next animation frame
let drawPending = false;

const fmt = (value, digits) => (value === null || value === undefined || Number.isNaN(value) ? "—" : value.toFixed(digits));

function say(text, isError = false) {
  const box = $("message");
  box.textContent = text;
  box.classList.toggle("error", isError);
}

async function api(method, path, body) {
  const headers = { Authorization: `Bearer ${localStorage.getItem(TOKEN_KEY) || ""}` };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const data = await response.json().catch(() => ({}));
  if (!response.ok) throw new Error(data.error || `${response.status} ${response.statusText}`);
  return data;
}

// -- live position -------------------------------------------------------------------------
function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/position`);
  ws.onmessage = (event) => {
    latest = JSON.parse(event.data);
    samples.push({ t: performance.now() / 1000, x: latest.x_mm, e: latest.error_um ?? null });
    if (!drawPending) {
      drawPending = true;
      requestAnimationFrame(draw);
    }
  };
  ws.onclose = () => setTimeout(connect, 1000);
}

function draw() {
  drawPending = false;
  if (latest) {
    $("position").textContent = fmt(latest.x_mm, 4);
    $("locked").textContent = latest.locked ? "locked" : "lost";
    $("grating").textContent = latest.reference_mm === undefined ? "—" : `${fmt(latest.reference_mm, 4)} mm`;
    $("error").textContent = latest.error_um === undefined ? "—" : `${fmt(latest.error_um, 2)} µm`;
    $("crlb").textContent = latest.crlb_um === null ? "—" : `${fmt(latest.crlb_um, 2)} µm`;
  }
  const now = performance.now() / 1000;
  while (samples.length && samples[0].t < now - PLOT_SECONDS) samples.shift();
  plot(now);
}

function plot(now) {
  const canvas = $("plot");
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  // Two bands, so that position and error never overlap: position above, error below, each with
  // its own scale; position labels on the left, error labels on the right.
  const series = (key, color, top, bottom, right) => {
    const values = samples.map((s) => s[key]).filter((v) => v !== null && Number.isFinite(v));
    if (values.length < 2) return;
    let lo = Math.min(...values), hi = Math.max(...values);
    if (hi - lo < 1e-9) { lo -= 0.5; hi += 0.5; }
    ctx.strokeStyle = color;
    ctx.beginPath();
    let started = false;
    for (const s of samples) {
      if (s[key] === null || !Number.isFinite(s[key])) { started = false; continue; }
      const px = canvas.width * (1 - (now - s.t) / PLOT_SECONDS);
      const py = bottom - (bottom - top) * (s[key] - lo) / (hi - lo);
      if (started) ctx.lineTo(px, py); else ctx.moveTo(px, py);
      started = true;
    }
    ctx.stroke();
    ctx.fillStyle = color;
    ctx.textAlign = right ? "right" : "left";
    const x = right ? canvas.width - 4 : 4;
    ctx.fillText(`${hi.toPrecision(5)}`, x, top + 4);
    ctx.fillText(`${lo.toPrecision(5)}`, x, bottom + 4);
  };
  const h = canvas.height;
  series("x", "#2b6cb0", 10, 0.55 * h - 6, false);
  series("e", "#b7791f", 0.55 * h + 10, h - 8, true);
}

// -- status --------------------------------------------------------------------------------
async function refresh() {
  try {
    const status = await (await fetch("/api/status")).json();
    const state = $("state");
    state.textContent = status.state;
    state.dataset.state = status.state;
    $("reason").textContent = status.reason || "";
    $("model").textContent = status.model || "no model: start a calibration";
    $("rate").textContent = fmt(status.frame_rate_hz, 1);
    if (!status.calibrated) $("position").textContent = "—";
    if (status.limits_mm) {
      $("limits").textContent = `soft limits ${status.limits_mm[0]} … ${status.limits_mm[1]} mm`;
      $("target").min = status.limits_mm[0];
      $("target").max = status.limits_mm[1];
    }
    const job = status.calibration;
    if (job) {
      $("progress").value = job.progress;
      $("calibration-message").textContent = `${job.id}: ${job.state} · ${Math.round(job.progress * 100)} % · ${job.message}`;
    }
    $("calibrate").disabled = status.state === "calibrating";
  } catch (err) {
    $("state").textContent = "offline";
    $("state").dataset.state = "fault";
  }
}

// -- actions -------------------------------------------------------------------------------
async function act(label, call) {
  try {
    const result = await call();
    say(label(result));
    refresh();
  } catch (err) {
    say(err.message, true);
  }
}

$("calibrate").addEventListener("click", () =>
  act((job) => `calibration ${job.id} started`, () => api("POST", "/api/calibration")));
$("stop").addEventListener("click", () => act(() => "stopped", () => api("POST", "/api/stage/stop")));
$("move-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const target = Number.parseFloat($("target").value);
  act((r) => `moving to ${r.target_mm} mm`, () => api("POST", "/api/stage/move", { target_mm: target }));
});
$("token-form").addEventListener("submit", (event) => {
  event.preventDefault();
  localStorage.setItem(TOKEN_KEY, $("token").value.trim());
  $("token").value = "";
  say("token saved in this browser");
});

connect();
refresh();
setInterval(refresh, 500);

// The status page: live position over /ws/position (decimated), state, line view, calibration,
// history and events from the API; calibrate / move / jog / home / velocity / stop / activate with
// the bearer token kept in localStorage. No libraries: the rig may be offline.
"use strict";

const TOKEN_KEY = "graytrack.token";
const STREAM_RATE = 60; // messages/s the page asks for: plenty for the eye, light at 1 kHz
const KEEP_S = 600;
const PROFILE_MS = 250;
const MAPS_MS = 2000; // the learned maps change over many frames, and are saved at most every 10 s
const $ = (id) => document.getElementById(id);
const samples = []; // {t (s, page clock), x (mm), e (µm or NaN)}
let latest = null;
let paused = false;
let status = null;
let lastEvent = 0;
let historyKey = "";
const calibratable = new Set(["tracking", "model"]); // faults during which a calibration still helps
const CONTROLS = ["move", "target", "jog-minus", "jog-plus", "jog-step", "home", "velocity", "set-velocity"];
const TOKEN_REASON = "save the bearer token under Access first";
let access = null; // GET /api/access: where the daemon's token is

// What the page's words mean, each said once: the tooltip of every element marked data-term="key"
// (where the word stands) and an entry of the glossary card (a phone has no hover).
const GLOSSARY = {
  position: ["position", "Where the camera is along the printed target, in mm, from this frame's pixels and the " +
    "calibrated model alone (the grating is not used for it)."],
  lock: ["lock", "locked: each frame is solved from the one before and the fit agrees with the image. lost: the " +
    "tracker lost its place within the print's period and is finding it again; positions until it is locked " +
    "again are not to be trusted."],
  grating: ["grating", "The stage's own position readout (its encoder grating, the controller's POS?), read for the " +
    "instant of the exposure: the reference the camera's position is checked against."],
  error: ["error", "position − grating for this frame, in µm: how far the camera's reading is from the stage's. " +
    "Judge it against the bound."],
  bound: ["bound", "The Cramér–Rao bound of this frame, in µm: the smallest standard deviation any unbiased reading " +
    "of these pixels can have, given the camera's noise and the slope of the model (σ / √Σ(∂F/∂x)²). An error " +
    "within about twice it is noise; far beyond it, the model misses something."],
  stale: ["stale", "The model no longer describes the images: something named after the word (light, focus, pixels, " +
    "magnification, scale …) changed since calibration. Positions still come, flagged, and may be off by more " +
    "than the bound: recalibrate."],
  rate: ["frames/s", "Frames the tracker placed per second, over up to its last 200 frames."],
  dropped: ["frames lost", "Camera frames that never reached the tracker since the daemon started (gaps in the " +
    "camera's frame counter); Events says when."],
  "held-out": ["held-out error", "A calibration's error std against the grating on frames its fit did not see: " +
    "what to expect while tracking, next to its bound."],
  texture: ["print texture", "Marks that settle on the printed target while the rig runs (dust, a smudge): the " +
    "tracker learns each one's place and depth from what the model leaves unexplained and takes it out, so it " +
    "does not pull the position. Kept with the model in use; dropped when another model is installed."],
  "print-map": ["print map", "What sits on the print (dust settled on it, a smudge) learned at its place along the " +
    "target: the share of the light it leaves there, with its σ. A place something landed on is set aside until " +
    "the motion has carried it across a pixel and shown that it moves with the print (a mark on the camera's side " +
    "stays at its pixels: the sensor map takes it). Kept with the model in use; dropped when another is installed."],
  "sensor-map": ["sensor map", "What sits on the camera's side (dust on its window, a veil) learned per pixel: a " +
    "gain (the share of the light it leaves) and an offset (light it scatters in), each with its σ. A pixel " +
    "something landed on is set aside until the stage's motion tells the camera's side from the print; then it " +
    "counts again, seen through its gain and offset. Kept with the model in use; dropped when another model is " +
    "installed."],
};

function explainTerms() {
  for (const element of document.querySelectorAll("[data-term]")) element.title = GLOSSARY[element.dataset.term][1];
  $("glossary").replaceChildren(...Object.entries(GLOSSARY).flatMap(([key, [word, text]]) => {
    const dt = document.createElement("dt");
    dt.id = `term-${key}`;
    dt.textContent = word;
    const dd = document.createElement("dd");
    dd.textContent = text;
    return [dt, dd];
  }));
}

const fmt = (value, digits) => (value === null || value === undefined || Number.isNaN(value) ? "—" : Number(value).toFixed(digits));

function say(text, isError = false) {
  const box = $("message");
  box.textContent = text;
  box.classList.toggle("error", isError);
}

const hasToken = () => Boolean(localStorage.getItem(TOKEN_KEY));
const tokenFile = () => (access && access.token_file) || "the daemon's token file";

// A request the daemon would refuse is not sent (the browser would log the refusal as an error):
// without a token the page says so itself.
async function api(method, path, body) {
  const token = localStorage.getItem(TOKEN_KEY);
  if (!token) throw new Error(`missing bearer token: save the contents of ${tokenFile()} under Access`);
  const headers = { Authorization: `Bearer ${token}` };
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const response = await fetch(path, { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const data = await response.json().catch(() => ({}));
  if (response.status === 401) throw new Error(`${data.error}: save the contents of ${tokenFile()} under Access`);
  if (!response.ok) throw new Error(data.error || `${response.status} ${response.statusText}`);
  return data;
}

async function get(path) {
  // reads carry the token when one is saved: a daemon bound beyond loopback asks for it ([daemon] read_token)
  const token = localStorage.getItem(TOKEN_KEY);
  const response = await fetch(path, token ? { headers: { Authorization: `Bearer ${token}` } } : undefined);
  const data = await response.json().catch(() => ({}));
  if (!response.ok) throw new Error(data.error || `${response.status} ${response.statusText}`);
  return data;
}

// -- live position -------------------------------------------------------------------------
function connect() {
  // the token as a subprotocol, never in the URL (URLs end up in logs): the daemon answers "graytrack"
  const token = localStorage.getItem(TOKEN_KEY);
  const protocols = token ? ["graytrack", `graytrack.bearer.${token}`] : [];
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/position?max_rate=${STREAM_RATE}`;
  const ws = new WebSocket(url, protocols);
  ws.onmessage = (event) => {
    latest = JSON.parse(event.data);
    const t = performance.now() / 1000;
    samples.push({ t, x: latest.x_mm ?? NaN, e: latest.error_um ?? NaN });
    while (samples.length && samples[0].t < t - KEEP_S) samples.shift();
  };
  ws.onclose = () => setTimeout(connect, 1000);
}

function draw() {
  if (latest) {
    $("position").textContent = fmt(latest.x_mm, 4);
    $("locked").textContent = latest.locked ? "locked" : "lost";
    $("grating").textContent = latest.reference_mm === undefined ? "—" : `${fmt(latest.reference_mm, 4)} mm`;
    $("error").textContent = latest.error_um === undefined ? "—" : `${fmt(latest.error_um, 2)} µm`;
    $("crlb").textContent = latest.crlb_um === null ? "—" : `${fmt(latest.crlb_um, 2)} µm`;
  }
  showStale();
  if (!paused) {
    const clipped = Plot.timeSeries($("plot"), samples, performance.now() / 1000, Number($("window").value));
    $("plot").dataset.clipped = String(clipped);
  }
  setTimeout(() => requestAnimationFrame(draw), 50);
}

// -- line view -----------------------------------------------------------------------------
async function refreshProfile() {
  // no frame before the rig is open: not asked (the 503 would be a console error on every first start)
  if (document.hidden) return;
  if (!status || status.state === "starting") {
    $("profile-info").textContent = "no line view until the rig is open";
    return;
  }
  const row = $("profile-row").value;
  try {
    const doc = await get(`/api/profile${row === "" ? "" : `?row=${row}`}`);
    Plot.profile($("profile"), doc);
    const canvas = $("profile");
    canvas.dataset.frameId = String(doc.frame_id);
    canvas.dataset.model = doc.model ? "yes" : "no";
    let info = `frame ${doc.frame_id} · ${doc.pixels.length} pixels · ${doc.rows} row(s)`;
    if (doc.residual) {
      const r = doc.residual.filter(Number.isFinite);
      const rms = Math.sqrt(r.reduce((a, v) => a + v * v, 0) / Math.max(r.length, 1));
      const sigma = doc.sigma.filter(Number.isFinite);
      const noise = Math.sqrt(sigma.reduce((a, v) => a + v * v, 0) / Math.max(sigma.length, 1));
      canvas.dataset.residualRms = rms.toFixed(3);
      canvas.dataset.noise = noise.toFixed(3);
      info += ` · x ${fmt(doc.x_mm, 4)} mm · residual rms ${fmt(rms, 2)} gray (noise ${fmt(noise, 2)} gray)`;
    } else {
      info += ` · ${doc.why_no_model}`;
    }
    if (doc.saturated.length) info += ` · ${doc.saturated.length} saturated`;
    if (doc.bad.length) info += ` · ${doc.bad.length} bad`;
    $("profile-info").textContent = info;
    const select = $("profile-row");
    if (select.options.length !== doc.rows + 1) {
      for (let i = select.options.length - 1; i < doc.rows; i++) select.add(new Option(`row ${i}`, String(i)));
    }
  } catch (err) {
    $("profile-info").textContent = `no line view: ${err.message}`;
  }
}

// -- learned maps --------------------------------------------------------------------------
let mapRows = 1; // rows of the sensor map (a model of one line has one: the rows averaged)

// The sensor map's line: what is learned and how sure, or honestly that nothing is (or that the engine keeps none).
function sensorMapLine(m) {
  if (!m) return "no sensor map: the engine in use keeps none ([daemon] engine = \"estimator\" does)";
  const notes = [m.restored ? `${m.restored} restored at start` : "", m.saved ? "" : "not saved yet"].filter(Boolean);
  const tail = notes.length ? ` · ${notes.join(" · ")}` : "";
  if (!m.learned.length) {
    return (m.touched.length ? `${m.touched.length} pixel(s) set aside, none yet resolved by the motion`
      : "nothing learned on the sensor's side") + tail;
  }
  const widest = m.marks.slice().sort((a, b) => b.samples - a.samples)[0];
  const where = widest ? ` · widest at row ${widest.row}, pixels ${widest.first_px}–${widest.last_px}: gain ` +
    `${fmt(widest.gain, 3)} ± ${fmt(widest.gain_sigma, 3)}, offset ${fmt(widest.offset_gray, 1)} ± ` +
    `${fmt(widest.offset_sigma_gray, 1)} gray` : "";
  return `${m.learned.length} pixel(s) learned in ${m.marks.length} mark(s)${where}${tail}`;
}

// The print map's line (the status's print_map): what is learned along the target and how sure, or honestly
// that nothing is.
function printMapLine(m) {
  if (!m) return "no print map: the engine in use keeps none ([daemon] engine = \"estimator\" does)";
  const notes = [m.restored ? `${m.restored} restored at start` : "", m.saved ? "" : "not saved yet"].filter(Boolean);
  const tail = notes.length ? ` · ${notes.join(" · ")}` : "";
  if (!m.marks) {
    return (m.touched_nodes ? `${m.touched_nodes} place(s) set aside, none yet decided by the motion`
      : "nothing learned on the print") + tail;
  }
  const widest = m.shown[0];
  const where = widest ? ` · widest at x_w = ${fmt(widest.x_mm, 3)} mm (${fmt(1000 * (widest.to_mm - widest.from_mm), 0)}` +
    ` µm): reflectance ${fmt(widest.reflectance, 3)} ± ${fmt(widest.reflectance_sigma, 3)}` : "";
  return `${m.marks} mark(s) learned on the print${where}${tail}`;
}

async function refreshMaps() {
  if (document.hidden || !status || status.state === "starting") return;
  const row = $("profile-row").value;
  try {
    const doc = await get(`/api/maps${row === "" || mapRows < 2 ? "" : `?row=${row}`}`);
    const sensor = doc.sensor_map && status.sensor_map
      ? { ...doc.sensor_map, saved: status.sensor_map.saved, restored: status.sensor_map.restored } : doc.sensor_map;
    mapRows = doc.sensor_map ? doc.sensor_map.rows : 1;
    Plot.sensorMap($("sensor-map"), doc.sensor_map);
    $("sensor-map").dataset.learned = doc.sensor_map ? String(doc.sensor_map.learned.length) : "";
    $("sensor-map").dataset.touched = doc.sensor_map ? String(doc.sensor_map.touched.length) : "";
    $("sensor-map-info").textContent = sensorMapLine(sensor);
    // the print as the engine in use keeps it: the estimator's map, or today's tracker's texture
    $("print-map-along").hidden = !doc.print_map && !!doc.texture;
    $("texture-along").hidden = !doc.texture && !!doc.print_map;
    Plot.printMap($("print-map"), doc.print_map, doc.stroke_mm);
    $("print-map").dataset.marks = doc.print_map ? String(doc.print_map.marks.length) : "";
    $("print-map").dataset.touched = doc.print_map ? String(doc.print_map.x_mm.length) : "";
    // (the status's counts; until the next poll has them, the same counted from this document)
    const shown = doc.print_map ? status.print_map || { touched_nodes: doc.print_map.x_mm.length, marks:
      doc.print_map.marks.length, shown: doc.print_map.marks.slice().sort((a, b) => b.nodes - a.nodes), saved: true,
      restored: 0 } : null;
    $("print-map-info").textContent = printMapLine(shown);
    Plot.textureMap($("texture-map"), doc.texture, doc.stroke_mm);
    $("texture-map").dataset.marks = doc.texture ? String(doc.texture.marks.length) : "";
    $("texture-map-info").textContent = doc.texture ? (doc.texture.marks.length
      ? `${doc.texture.marks.length} mark(s) learned on the print` : "nothing learned on the print")
      : "no print texture: the engine in use keeps none ([daemon] engine = \"watches\" does)";
  } catch (err) {
    $("sensor-map-info").textContent = `no maps: ${err.message}`;
  }
}

// -- access --------------------------------------------------------------------------------
// The token file named by its path on the daemon's machine (a newcomer has no idea what "DATA" is),
// and whether this browser holds a token: without one every control is disabled and says so.
async function loadAccess() {
  try {
    access = await get("/api/access");
  } catch (err) {
    access = null;
  }
  showAccess();
}

function showAccess() {
  const where = $("token-where");
  const path = access && access.token_file;
  if (path) {
    const code = document.createElement("code");
    code.textContent = `cat ${path}`;
    where.replaceChildren(`Calibrate, move and activate need the daemon's bearer token: the contents of ${path} ` +
      "(on the daemon's machine: ", code, ").");
  } else {
    const need = "Calibrate, move and activate need the daemon's bearer token";
    where.textContent = access ? `${need}: the [daemon] token of its configuration.`
      : `${need} (its data directory's token file).`;
  }
  $("token").placeholder = path ? `contents of ${path}` : "the daemon's token";
  $("token-state").textContent = hasToken() ? "A token is saved in this browser (only here); the controls use it."
    : "No token saved in this browser yet: the controls stay disabled until one is.";
}

// -- status, controls ----------------------------------------------------------------------
function setDisabled(ids, reason) {
  for (const id of ids) {
    $(id).disabled = reason !== "";
    $(id).title = reason;
  }
}

function holdControls(reason) {
  $("controls-reason").textContent = reason;
  setDisabled([...CONTROLS, "stop", "calibrate"], reason);
}

function controlsReason(s) {
  if (s.state === "calibrating") return `calibration ${s.calibration.id} is running: moves are disabled (Stop aborts it)`;
  if (s.state === "fault") return `disabled during the fault: ${s.reason}`;
  if (s.state === "starting") {
    return s.startup ? "disabled while the daemon warms up" : "disabled until the hardware is open";
  }
  if (s.state === "stopping") return "the daemon is shutting down";
  return "";
}

// Marks learned on the print (dust settled on it), kept with the model in use: how many, the newest's
// place on the target and how sure, restored at start or not yet saved.
function textureLine(t) {
  if (!t) return "not learning";
  const notes = [t.restored ? `${t.restored} restored at start` : "", t.saved ? "" : "not saved yet"].filter(Boolean);
  const tail = notes.length ? ` · ${notes.join(" · ")}` : "";
  if (t.marks === 0) return `nothing learned on the print${tail}`;
  const newest = t.newest[0];
  const sure = newest.depth_sigma === null ? "" : ` ± ${fmt(100 * newest.depth_sigma, 1)} %`;
  const where = `newest at x_w = ${fmt(newest.x_mm, 3)} mm`;
  return `${t.marks} mark${t.marks === 1 ? "" : "s"} learned on the print · ${where} ` +
    `(${fmt(100 * newest.depth, 1)} %${sure} of the light, ${newest.frames} frames)${tail}`;
}

// The model's validity where the position is read: the frame's own flag from the stream, or the
// daemon's verdict from the status (which holds while frames are flagged), with the family of causes.
function showStale() {
  const frame = latest && latest.stale ? latest.stale_reason : null;
  const model = status && status.model_stale ? status.stale_reason : null;
  const stale = Boolean((latest && latest.stale) || (status && status.model_stale));
  const flag = $("position-stale");
  flag.hidden = !stale;
  const reason = frame || model;
  flag.textContent = stale ? (reason ? `stale: ${reason}` : "stale") : "";
  $("position").classList.toggle("stale", stale);
}

function applyStatus(s) {
  status = s;
  const state = $("state");
  state.textContent = s.state;
  state.dataset.state = s.state;
  const warming = s.startup ? `${s.startup.step}: ${fmt(s.startup.elapsed_s, 0)} s (${s.startup.expected_s})` : "";
  $("reason").textContent = s.reason || warming;
  const staleNote = $("model-stale");
  staleNote.hidden = !s.model_stale;
  staleNote.textContent = s.model_stale ? `model stale: ${s.stale_reason} changed since calibration — recalibrate` : "";
  showStale();
  $("sim-badge").hidden = !s.simulated;
  $("model").textContent = s.model || (s.state === "starting" ? "—" : s.state === "calibrating"
    ? "no model yet: the calibration running makes one" : "no model: start a calibration");
  $("dropped").textContent = String(s.dropped);
  const lost = $("dropped-note");
  lost.hidden = !s.dropped;
  lost.textContent = s.dropped ? `frames lost: ${s.dropped} of the ${s.frames + s.dropped} camera frames since the ` +
    `daemon started never reached the tracker (${fmt(100 * s.dropped / (s.frames + s.dropped), 1)} %; gaps in the ` +
    "camera's frame counter: the frame loop fell behind the camera, or the link lost them); Events says when" : "";
  const active = s.active_calibration;
  $("active-calibration").textContent = active && active.error_std_um !== undefined && active.error_std_um !== null
    ? `held-out error ${fmt(active.error_std_um, 2)} µm · bound ${fmt(active.bound_um, 2)} µm (calibration ${active.id})`
    : (active ? `calibration ${active.id}` : "");
  $("rate").textContent = fmt(s.frame_rate_hz, 1);
  // the print as the engine in use keeps it: the estimator's map, or today's tracker's texture
  $("texture").textContent = s.print_map ? printMapLine(s.print_map) : textureLine(s.texture);
  $("texture").dataset.marks = s.print_map ? String(s.print_map.marks) : s.texture ? String(s.texture.marks) : "";
  if (s.position_mm === null) $("position").textContent = "—";
  if (s.limits_mm) {
    $("limits").textContent = `soft limits ${s.limits_mm[0]} … ${s.limits_mm[1]} mm`;
    $("target").min = s.limits_mm[0];
    $("target").max = s.limits_mm[1];
  }
  const moving = $("moving");
  moving.dataset.moving = String(s.moving);
  moving.textContent = s.moving === null ? "" : s.moving
    ? `moving${s.target_mm === null ? "" : ` → ${s.target_mm} mm`}` : "at rest";
  if (s.velocity_mm_s !== null && document.activeElement !== $("velocity")) $("velocity").placeholder = `${s.velocity_mm_s}`;
  const job = s.calibration;
  if (job) {
    $("progress").value = job.progress;
    const ended = ["failed", "aborted", "interrupted"].includes(job.state);
    $("calibration-message").textContent = `${job.id}: ${job.state}${ended ? ` at ${Math.round(job.progress * 100)} %` : ` · ${Math.round(job.progress * 100)} %`} · ${job.message}`;
  }
  const tokenReason = hasToken() ? "" : TOKEN_REASON;
  const reason = controlsReason(s) || tokenReason;
  $("controls-reason").textContent = reason;
  setDisabled(CONTROLS, reason);
  setDisabled(["stop"], tokenReason);
  const blocking = Object.keys(s.faults || {}).filter((k) => !calibratable.has(k));
  const calibrateReason = s.state === "calibrating" ? "a calibration is running"
    : ["starting", "stopping"].includes(s.state) ? reason : blocking.length ? `disabled during the fault: ${s.reason}` : "";
  setDisabled(["calibrate"], calibrateReason || tokenReason);
  for (const button of document.querySelectorAll("#history button")) button.disabled = reason !== "" || button.dataset.active === "true";
  const key = `${job ? job.id + job.state : ""}|${active ? active.id : ""}`;
  if (key !== historyKey) {
    historyKey = key;
    refreshHistory();
  }
}

async function refresh() {
  try {
    applyStatus(await get("/api/status"));
  } catch (err) {
    $("state").textContent = "offline";
    $("state").dataset.state = "fault";
    holdControls("the daemon does not answer");
  }
}

// -- history and events --------------------------------------------------------------------
async function refreshHistory() {
  try {
    const page = await get("/api/calibrations?limit=20");
    const body = $("history").tBodies[0];
    body.replaceChildren(...page.items.map((c) => {
      const tr = document.createElement("tr");
      tr.dataset.id = c.id;
      tr.classList.toggle("active", c.active);
      const when = new Date(c.finished).toLocaleString();
      const quality = c.error_std_um === null ? "—" : `${fmt(c.error_std_um, 2)} µm (bound ${fmt(c.bound_um, 2)} µm)`;
      const cells = [when, quality, c.model || c.model_kind];
      for (const text of cells) { const td = document.createElement("td"); td.textContent = text; tr.append(td); }
      const actions = document.createElement("td");
      if (c.files.includes("report.html")) {
        const link = document.createElement("a");
        link.href = `/api/calibrations/${c.id}/files/report.html`;
        link.target = "_blank"; link.rel = "noopener"; link.textContent = "report";
        link.className = "report-link";
        actions.append(link, " ");
      }
      const button = document.createElement("button");
      button.type = "button";
      button.className = "secondary activate";
      button.dataset.active = String(c.active);
      button.textContent = c.active ? "active" : "Activate";
      button.disabled = c.active;
      button.addEventListener("click", () => {
        // Activating changes the model every position comes from: ask first.
        if (!window.confirm(`Track with the model of calibration ${c.id} (${quality}) from now on?`)) return;
        act((r) => `calibration ${r.active} is active`, () => api("POST", `/api/calibrations/${c.id}/activate`));
      });
      actions.append(button);
      tr.prepend(actions); // first, so a narrow screen never has to scroll to reach it
      return tr;
    }));
  } catch (err) {
    say(`history: ${err.message}`, true);
  }
}

// Events of one kind in a row (frames lost, one every 10 s on a loaded host) are one line with their
// count, the span of times and the newest message, so the rare ones (a calibration done, a model
// installed) are not pushed out of view; those, and faults, each keep a line of their own.
const EVENTS_APART = new Set(["fault", "recovered", "model_installed", "model_stale", "model_fresh", "geometry",
  "calibration_started", "calibration_done", "calibration_failed", "calibration_aborted", "calibration_interrupted"]);

function addEvent(list, e) {
  const when = new Date(e.t_unix * 1000).toLocaleTimeString();
  const top = list.firstElementChild;
  if (top && top.dataset.kind === e.kind && !EVENTS_APART.has(e.kind)) {
    const count = Number(top.dataset.count) + 1;
    top.dataset.count = String(count);
    top.querySelector(".count").textContent = `×${count}`;
    top.querySelector("time").textContent = `${top.dataset.first}–${when}`;
    top.querySelector(".text").textContent = e.message;
    top.title = `${count} ${e.kind} events in a row from ${top.dataset.first} to ${when}; the newest shown`;
    return;
  }
  const li = document.createElement("li");
  li.dataset.kind = e.kind;
  li.dataset.count = "1";
  li.dataset.first = when;
  li.classList.toggle("apart", EVENTS_APART.has(e.kind));
  const time = document.createElement("time");
  time.textContent = when;
  const count = document.createElement("span");
  count.className = "count";
  const text = document.createElement("span");
  text.className = "text";
  text.textContent = e.message;
  li.append(time, count, text);
  list.prepend(li);
}

async function refreshEvents() {
  try {
    const events = await get(`/api/events?since=${lastEvent}`);
    const list = $("events");
    for (const e of events) {
      lastEvent = Math.max(lastEvent, e.id);
      addEvent(list, e);
    }
    while (list.children.length > 200) list.lastElementChild.remove();
  } catch (err) {
    // the status line already says when the daemon is offline
  }
}

// -- actions -------------------------------------------------------------------------------
async function act(label, call) {
  try {
    const result = await call();
    say(label(result));
  } catch (err) {
    say(err.message, true);
  }
  refresh();
}

function number(id, what) {
  const text = $(id).value.trim();
  const value = Number(text);
  if (text === "" || !Number.isFinite(value)) throw new Error(`${what}: enter a number`);
  return value;
}

function withinLimits(name, target) {
  const limits = status && status.limits_mm;
  if (limits && !(target >= limits[0] && target <= limits[1])) {
    throw new Error(`${name} ${target} is outside the soft limits [${limits[0]}, ${limits[1]}] mm`);
  }
  return target;
}

$("calibrate").addEventListener("click", () =>
  act((job) => `calibration ${job.id} started`, () => api("POST", "/api/calibration")));
$("stop").addEventListener("click", () => act((r) => r.aborted_calibration ? `stopped; calibration ${r.aborted_calibration} aborted` : "stopped",
  () => api("POST", "/api/stage/stop")));
$("move-form").addEventListener("submit", (event) => {
  event.preventDefault();
  act((r) => `moving to ${r.target_mm} mm`, async () =>
    api("POST", "/api/stage/move", { target_mm: withinLimits("target_mm", number("target", "target")) }));
});
for (const [id, sign] of [["jog-minus", -1], ["jog-plus", 1]]) {
  $(id).addEventListener("click", () => act((r) => `moving to ${r.target_mm} mm`, async () => {
    const step = sign * Number($("jog-step").value);
    if (status && status.grating_mm !== null) withinLimits("target_mm", Math.round((status.grating_mm + step) * 1e6) / 1e6);
    return api("POST", "/api/stage/jog", { step_mm: step });
  }));
}
$("home").addEventListener("click", () => act(() => "referenced (home)", () => api("POST", "/api/stage/home")));
$("velocity-form").addEventListener("submit", (event) => {
  event.preventDefault();
  act((r) => `velocity ${r.velocity_mm_s} mm/s`, async () =>
    api("POST", "/api/stage/velocity", { velocity_mm_s: number("velocity", "velocity") }));
});
$("pause").addEventListener("click", () => {
  paused = !paused;
  $("pause").textContent = paused ? "Resume" : "Pause";
});
$("token-form").addEventListener("submit", (event) => {
  event.preventDefault();
  localStorage.setItem(TOKEN_KEY, $("token").value.trim());
  $("token").value = "";
  say("token saved in this browser");
  showAccess();
  refresh(); // the controls follow at once
});

explainTerms();
holdControls("waiting for the daemon's first status");
loadAccess();
connect();
refresh();
refreshEvents();
refreshProfile();
setInterval(refresh, 500);
setInterval(refreshMaps, MAPS_MS);
setInterval(refreshEvents, 2000);
setInterval(refreshProfile, PROFILE_MS);
requestAnimationFrame(draw);

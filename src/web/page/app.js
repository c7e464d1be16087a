// The operator page: newest layer of every view, any earlier layer, timeline and health.
// Updates arrive as server-sent events (/api/events); no polling.
"use strict";
const $ = (id) => document.getElementById(id);
const state = {
  views: [], layers: [], byLayer: new Map(), newest: null, current: null, expected: null,
  rectified: false, vectors: false, follow: true, svg: new Map(),
};
window.layerwisePageLoadedAt = Date.now();

async function getJson(url) {
  const r = await fetch(url, { credentials: "same-origin" });
  if (!r.ok) throw new Error(url + ": " + r.status);
  return r.json();
}

function fmtBytes(b) { return b == null ? "?" : (b / 1e9).toFixed(1) + " GB"; }
function fmtAge(t) {
  if (!t) return "never";
  const s = Math.round((Date.now() - Date.parse(t)) / 1000);
  return s < 120 ? s + " s ago" : Math.round(s / 60) + " min ago";
}
function dd(dl, key, value, cls) {
  const dt = document.createElement("dt"); dt.textContent = key;
  const d = document.createElement("dd"); d.textContent = value; if (cls) d.className = cls;
  dl.append(dt, d);
}

function showStatus(s) {
  if (!s) return;
  $("build-name").textContent = s.name || "layerwise";
  $("state").textContent = "daemon " + s.state + (s.pid ? " (pid " + s.pid + ")" : "") + (!s.running && s.last_update ? ", " + s.last_update : "");
  const w = $("warning");
  const raised = s.alarm && (s.alarm.state === "raised" || s.alarm.state === "unreadable");
  const alarm = !raised ? "" : s.alarm.state === "raised"
    ? "ALARM since layer " + s.alarm.layer + ": " + s.alarm.message
    : "ALARM UNKNOWN (treat it as raised): " + s.alarm.reason;
  const banner = [alarm, s.warning].filter(Boolean).join(" \u2014 ");
  w.hidden = !banner; $("warning-text").textContent = banner;
  $("ack-form").hidden = !(s.alarm && s.alarm.state === "raised");
  $("ack-cli").textContent = raised ? "or: layerwise alarm ack --build " + s.build_dir : "";
  const alarmKey = JSON.stringify(s.alarm || null);
  if (alarmKey !== state.alarmKey) { state.alarmKey = alarmKey; loadAlarmHistory(); }
  const h = $("health"); h.replaceChildren();
  if (s.health && Object.keys(s.health).length) {
    // The daemon's own health report: the same words as `layerwise status` and STATUS=.
    const cls = { ok: "ok", warning: "wait", error: "bad" };
    for (const part of ["trigger", "camera", "lights", "processing", "disk"]) {
      const p = s.health[part];
      if (!p) continue;
      let text = p.summary;
      if (part === "disk" && s.bytes_needed != null) text += ", rest of build needs " + fmtBytes(s.bytes_needed);
      dd(h, part, text + (p.warning ? " \u2014 " + p.warning : ""), cls[p.state] || "");
    }
    if (s.pacs && s.pacs.length) for (const d of s.pacs) dd(h, "pacs " + d.destination, d.pushed + " pushed, " + d.pending + " pending, " + d.failed + " failed" + (d.last_error ? " \u2014 " + d.last_error : ""), d.last_error || d.failed ? "wait" : "ok");
    if (s.irregular && s.irregular.length) dd(h, "signals", s.irregular.length + " irregular: " + s.irregular[s.irregular.length - 1], "wait");
    $("layer-of").textContent = s.layers_expected ? "of " + s.layers_expected : "";
    return;
  }
  // A build written before the daemon reported health: what status.json held then.
  const t = s.trigger;
  if (t) dd(h, "trigger", t.source + (t.connected ? " connected" : " NOT CONNECTED") + ", last signal " + fmtAge(t.last_signal_at), t.connected ? "ok" : "bad");
  else dd(h, "trigger", "no report (daemon not running?)");
  const last = Object.values(s.last_frames || {}).map((f) => f.at).sort().pop();
  dd(h, "camera", "last frame " + fmtAge(last) + ", " + s.frames + " stored, " + s.frames_missing + " missing, " + s.retakes + " retakes", s.frames_missing ? "bad" : "ok");
  dd(h, "lights", (state.views.length ? state.views.join(", ") : "–"));
  let disk = fmtBytes(s.free_bytes) + " free";
  if (s.bytes_needed != null) disk += ", rest of build needs " + fmtBytes(s.bytes_needed);
  dd(h, "disk", disk, s.warning && s.warning.includes("free") ? "bad" : "ok");
  dd(h, "backlog", s.waiting_for_processing + " frames waiting (queue " + s.queue_depth + ")", s.waiting_for_processing > 12 ? "wait" : "ok");
  if (s.irregular && s.irregular.length) dd(h, "signals", s.irregular.length + " irregular: " + s.irregular[s.irregular.length - 1], "wait");
  $("layer-of").textContent = s.layers_expected ? "of " + s.layers_expected : "";
}

// The alarm's history, newest first: raised, acknowledged (who, note), cleared.
async function loadAlarmHistory() {
  let h;
  try { h = await getJson("/api/alarm"); } catch (e) { $("alarm-history").textContent = "cannot read the alarm history: " + e.message; return; }
  const time = (t) => new Date(t).toLocaleString();
  const items = h.events.slice().reverse().map((e) => {
    const li = document.createElement("li"); li.className = "alarm-" + e.event;
    if (e.event === "raised") li.textContent = time(e.at) + " raised at layer " + e.layer + " (" + e.kind + ", " + e.severity + "): " + e.message;
    else if (e.event === "acknowledged") li.textContent = time(e.at) + " acknowledged by " + e.by + (e.note ? ": " + e.note : "");
    else li.textContent = time(e.at) + " cleared at layer " + e.layer;
    if (e.layer) { li.dataset.layer = e.layer; li.addEventListener("click", () => { setFollow(false); showLayer(e.layer); }); }
    return li;
  });
  if (!items.length) { const li = document.createElement("li"); li.textContent = "never raised"; items.push(li); }
  $("alarm-history").replaceChildren(...items);
}

$("ack-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  const by = $("ack-by").value.trim();
  if (!by) { $("ack-result").textContent = "say who acknowledges"; $("ack-by").focus(); return; }
  localStorage.setItem("layerwise-operator", by);
  const r = await fetch("/api/alarm/ack", {
    method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/json" },
    body: JSON.stringify({ by, note: $("ack-note").value }),
  });
  const answer = await r.json().catch(() => ({}));
  $("ack-result").textContent = r.ok ? "alarm " + answer.shown : "not acknowledged: " + (answer.error || r.status);
  if (r.ok) { $("ack-note").value = ""; getJson("/api/status").then(showStatus).catch(() => {}); }
});
$("ack-by").value = localStorage.getItem("layerwise-operator") || "";

// Next / previous layer with an inspection flag.
function flagged(direction) {
  const from = state.current || 0;
  const list = state.layers.filter((l) => l.flags && (direction > 0 ? l.layer > from : l.layer < from));
  const l = direction > 0 ? list[0] : list[list.length - 1];
  if (l) { setFollow(false); showLayer(l.layer); }
}
$("next-flag").addEventListener("click", () => flagged(1));
$("prev-flag").addEventListener("click", () => flagged(-1));

// Deep links: #layer=N (the layer shown is always in the address, to copy and send).
function layerFromHash() {
  const m = /(?:^#|&)layer=(\d{1,5})(?:&|$)/.exec(location.hash);
  return m ? Number(m[1]) : null;
}
window.addEventListener("hashchange", () => { const n = layerFromHash(); if (n && n !== state.current) { setFollow(false); showLayer(n); } });

async function loadLayers() {
  const j = await getJson("/api/layers");
  // Following the build shows the newest layer with all its views; the one being captured is
  // a click (or End) away.
  const before = state.byLayer && JSON.stringify(state.byLayer.get(state.current));
  state.views = j.views; state.layers = j.layers; state.newest = j.complete || j.newest;
  state.expected = j.layers_expected; state.rectified = j.rectified; state.vectors = j.vectors;
  state.byLayer = new Map(j.layers.map((l) => [l.layer, l]));
  // The layer shown changed (its frames processed, inspected, flagged): show it as it is now.
  const changed = before !== undefined && before !== JSON.stringify(state.byLayer.get(state.current));
  const slider = $("slider");
  const max = Math.max(1, j.newest || 1, ...j.layers.map((l) => l.layer));
  slider.max = max;
  drawTimeline();
  if (state.linked) { const n = state.linked; state.linked = null; showLayer(n); }
  else if (state.follow && state.newest && state.newest !== state.current) showLayer(state.newest);
  else if (state.current == null && state.newest) showLayer(state.newest);
  else if (changed) showLayer(state.current);
  $("newest-note").textContent = state.follow || state.current === state.newest ? "" : "(newest: " + state.newest + ")";
}

function cellClass(l) {
  const flagged = l.worst ? " flagged-" + l.worst : "";
  if (l.missing || l.failed) return "bad" + flagged;
  if (l.processed < l.stored) return "wait" + flagged;
  return flagged;
}

// The inspection flags of `view` as outlined boxes over a rectified picture, or over the crop
// `region` of it (fractions of the picture); null when there are none.
function flagBoxes(flags, view, region) {
  const r = region || { x: 0, y: 0, w: 1, h: 1 };
  const mine = (flags || []).filter((f) => f.box && f.draw_on.includes(view));
  if (!mine.length) return null;
  const layer = document.createElement("div");
  layer.className = "flags";
  for (const f of mine) {
    const b = document.createElement("div");
    b.className = "flag-box " + f.severity;
    b.dataset.kind = f.kind;
    b.style.left = (100 * (f.box.x - r.x) / r.w) + "%";
    b.style.top = (100 * (f.box.y - r.y) / r.h) + "%";
    b.style.width = (100 * f.box.w / r.w) + "%";
    b.style.height = (100 * f.box.h / r.h) + "%";
    b.title = f.message + " (score " + f.score.toFixed(2) + ", threshold " + f.threshold.toFixed(2) + ", " + f.severity + ")";
    const t = document.createElement("span");
    t.textContent = f.kind + " " + f.score.toFixed(1);
    b.append(t);
    layer.append(b);
  }
  return layer;
}

// The powder bed the inspection judges (found over the build's first layers, then kept) as a
// faint dashed outline over a rectified pre-scan view, or over the crop `region` of it
// (fractions of the picture); null on the other views and before the bed settled.
function bedOutline(bed, view, region) {
  if (!bed || !view.startsWith("pre_") || bed.outline.length < 3) return null;
  const r = region || { x: 0, y: 0, w: 1, h: 1 };
  const ns = "http://www.w3.org/2000/svg";
  const svg = document.createElementNS(ns, "svg");
  svg.setAttribute("class", "bed-outline");
  svg.setAttribute("viewBox", [r.x, r.y, r.w, r.h].join(" "));
  svg.setAttribute("preserveAspectRatio", "none");
  const line = document.createElementNS(ns, "polygon");
  line.setAttribute("points", bed.outline.map(([x, y]) => x + "," + y).join(" "));
  svg.append(line);
  return svg;
}

function drawTimeline() {
  const tl = $("timeline");
  const maxLag = Math.max(1000, ...state.layers.map((l) => l.lag_ms || 0));
  const cells = state.layers.map((l) => {
    const c = document.createElement("div");
    c.className = "cell " + cellClass(l) + (l.layer === state.current ? " current" : "");
    c.dataset.layer = l.layer;
    c.style.height = (20 + 80 * (l.lag_ms || 0) / maxLag) + "%";
    c.title = "layer " + l.layer + ": " + l.stored + " stored, " + l.processed + " rectified, " + l.missing + " missing, " + l.failed + " failed" + (l.lag_ms != null ? ", lag " + l.lag_ms + " ms" : "") + (l.flags ? ", " + l.flags + " flags" + (l.worst ? " (" + l.worst + ")" : "") : "");
    return c;
  });
  tl.replaceChildren(...cells);
}

$("timeline").addEventListener("click", (e) => {
  const n = e.target.dataset && e.target.dataset.layer;
  if (n) { setFollow(false); showLayer(Number(n)); }
});

function setFollow(on) { state.follow = on; $("follow").checked = on; }

async function vectorsSvg(n) {
  if (!state.vectors) return "";
  if (!state.svg.has(n)) {
    const r = await fetch("/api/layers/" + n + "/vectors.svg");
    state.svg.set(n, r.ok ? await r.text() : "");
    if (state.svg.size > 20) state.svg.delete(state.svg.keys().next().value);
  }
  return state.svg.get(n);
}

function kind() { return $("raw").checked || !state.rectified ? "raw" : "rectified"; }

async function showLayer(n) {
  n = Math.max(1, Math.min(Number($("slider").max), n));
  state.current = n;
  if (layerFromHash() !== n) history.replaceState(null, "", "#layer=" + n);
  $("layer-number").textContent = n;
  $("slider").value = n;
  document.querySelectorAll("#timeline .cell.current").forEach((c) => c.classList.remove("current"));
  const cell = document.querySelector('#timeline .cell[data-layer="' + n + '"]');
  if (cell) cell.classList.add("current");
  let detail;
  try { detail = await getJson("/api/layers/" + n); } catch (e) { detail = null; }
  if (state.current !== n) return;
  const svg = kind() === "rectified" ? await vectorsSvg(n) : "";
  const tiles = state.views.map((view) => {
    const t = document.createElement("div");
    const v = detail && detail.views[view];
    t.className = "tile " + (v ? v.state : "none") + (kind() === "raw" ? " raw" : "");
    t.dataset.view = view; t.dataset.layer = n;
    const p = detail && detail.pictures[view];
    if (p) {
      const img = document.createElement("img");
      img.alt = "layer " + n + " " + view; img.src = p[kind()]; img.dataset.layer = n;
      t.append(img);
      if (svg) { const o = document.createElement("div"); o.className = "vectors"; o.innerHTML = svg; t.append(o); }
      const bed = kind() === "rectified" && bedOutline(detail.bed, view);
      if (bed) t.append(bed);
      const boxes = kind() === "rectified" && flagBoxes(detail.inspection, view);
      if (boxes) t.append(boxes);
      if (kind() === "rectified") t.append(heatLayer(n, view));
      t.addEventListener("click", () => openZoom(n, view, p, detail.inspection, detail.bed));
    }
    const label = document.createElement("span"); label.className = "label"; label.textContent = view;
    const st = document.createElement("span"); st.className = "state";
    st.textContent = v ? v.state + (v.lag_ms != null ? " · " + v.lag_ms + " ms" : "") + (v.reason ? ": " + v.reason : "") : "no frame";
    t.append(label, st);
    return t;
  });
  $("views").replaceChildren(...tiles);
  const d = $("layer-detail"); d.replaceChildren();
  if (detail) {
    const s = detail.summary;
    dd(d, "frames", s.stored + " stored, " + s.missing + " missing");
    dd(d, "rectified", s.processed + (s.failed ? ", " + s.failed + " failed" : ""), s.failed ? "bad" : "ok");
    if (s.lag_ms != null) dd(d, "lag", s.lag_ms + " ms");
    for (const [phase, at] of Object.entries(detail.signals)) dd(d, phase + " signal", new Date(at).toLocaleTimeString());
    for (const f of detail.flags) dd(d, "flag", f, "wait");
    if (detail.bed) dd(d, "powder bed", Math.round(detail.bed.area_mm2) + " mm\u00b2 judged (settled at layer " + detail.bed.layer + ")");
    for (const f of detail.inspection || []) flagEntry(d, n, f);
  }
  $("newest-note").textContent = state.follow || n === state.newest || !state.newest ? "" : "(newest: " + state.newest + ")";
}

// The model's heat map over a rectified view ([inspection.model]: per-tile defect probability,
// white = defect), tinted red; absent without a model. Toggled with H.
function heatLayer(n, view) {
  const img = document.createElement("img");
  img.className = "heatmap"; img.alt = ""; img.src = "/api/layers/" + n + "/" + view + "/heatmap.png";
  img.style.cssText = "position:absolute;left:0;top:0;width:100%;height:100%;opacity:.45;pointer-events:none;filter:sepia(1) saturate(6) hue-rotate(-40deg);mix-blend-mode:screen";
  img.onerror = () => img.remove();
  return img;
}
function addHeatToggle() {
  const label = document.createElement("label");
  label.innerHTML = '<input id="heat" type="checkbox" checked> heat map (H)';
  document.querySelector(".controls").append(label);
  $("heat").addEventListener("change", (e) => document.body.classList.toggle("no-heat", !e.target.checked));
  const style = document.createElement("style");
  style.textContent = "body.no-heat .heatmap { display: none; } .verdict { margin-left: .4em; font-size: .8em; }";
  document.head.append(style);
  document.addEventListener("keydown", (e) => { if (e.key === "h" && e.target.tagName !== "INPUT") $("heat").click(); });
}
addHeatToggle();

// A flag in the layer's list, with the operator's verdict buttons: "confirm" or "false alarm"
// (recorded with who and when in the build's verdicts.jsonl; the model learns from them).
function flagEntry(dl, n, f) {
  const what = (f.class ? f.class + ": " : "") + f.message + " (" + f.severity + ", score " + f.score.toFixed(2) + ")";
  dd(dl, f.kind, what, f.severity === "critical" ? "bad" : "wait");
  const d = dl.lastElementChild;
  for (const [verdict, text] of [["confirm", "confirm"], ["false_alarm", "false alarm"]]) {
    const b = document.createElement("button");
    b.className = "verdict"; b.textContent = text; b.dataset.verdict = verdict;
    b.addEventListener("click", () => sendVerdict(n, f, verdict, d));
    d.append(b);
  }
}
async function sendVerdict(n, f, verdict, d) {
  const who = localStorage.getItem("layerwise-who") || prompt("Your name (recorded with the verdict)") || "operator";
  localStorage.setItem("layerwise-who", who);
  const body = { view: f.view, flag: { kind: f.kind, class: f.class, bbox_mm: f.bbox_mm }, verdict, who };
  const r = await fetch("/api/layers/" + n + "/verdicts", {
    method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  });
  const note = document.createElement("span"); note.className = "verdict";
  note.textContent = r.ok ? "✓ " + verdict.replace("_", " ") + " by " + who : "not recorded: " + ((await r.json().catch(() => ({}))).error || r.status);
  d.querySelectorAll("button.verdict").forEach((b) => b.remove());
  d.append(note);
}

// Zoom: the preview on the left, a full-resolution crop around the clicked point on the right.
let zoomed = null;
async function openZoom(n, view, p, flags, bed) {
  zoomed = { n, view, p, kind: kind(), flags: flags || [], bed };
  $("zoom-title").textContent = "layer " + n + " " + view + " (" + zoomed.kind + ")";
  $("zoom-img").src = p[zoomed.kind];
  $("zoom-original").href = p.original;
  $("zoom-vectors").innerHTML = zoomed.kind === "rectified" ? await vectorsSvg(n) : "";
  const boxes = zoomed.kind === "rectified" && flagBoxes(zoomed.flags, view);
  const outline = zoomed.kind === "rectified" && bedOutline(bed, view);
  $("zoom-flags").replaceChildren(...[outline, boxes].filter(Boolean));
  $("zoom-crop-frame").hidden = true;
  $("zoom").hidden = false;
}
$("zoom-img").addEventListener("click", (e) => {
  const r = e.target.getBoundingClientRect();
  const fx = (e.clientX - r.left) / r.width, fy = (e.clientY - r.top) / r.height;
  const w = 0.1, h = 0.1;
  const x = Math.min(1 - w, Math.max(0, fx - w / 2)), y = Math.min(1 - h, Math.max(0, fy - h / 2));
  const c = $("zoom-crop");
  c.src = zoomed.p[zoomed.kind] + "&x=" + x.toFixed(4) + "&y=" + y.toFixed(4) + "&w=" + w + "&h=" + h;
  const region = { x: Number(x.toFixed(4)), y: Number(y.toFixed(4)), w, h };
  const boxes = zoomed.kind === "rectified" && flagBoxes(zoomed.flags, zoomed.view, region);
  const outline = zoomed.kind === "rectified" && bedOutline(zoomed.bed, zoomed.view, region);
  $("zoom-crop-flags").replaceChildren(...[outline, boxes].filter(Boolean));
  $("zoom-crop-frame").hidden = false;
});
function closeZoom() { $("zoom").hidden = true; zoomed = null; }
$("zoom-close").addEventListener("click", closeZoom);

$("slider").addEventListener("input", (e) => { setFollow(false); showLayer(Number(e.target.value)); });
$("prev").addEventListener("click", () => { setFollow(false); showLayer(state.current - 1); });
$("next").addEventListener("click", () => { setFollow(false); showLayer(state.current + 1); });
$("follow").addEventListener("change", (e) => { setFollow(e.target.checked); if (state.follow && state.newest) showLayer(state.newest); });
$("overlay").addEventListener("change", (e) => document.body.classList.toggle("no-overlay", !e.target.checked));
$("flags").addEventListener("change", (e) => document.body.classList.toggle("no-flags", !e.target.checked));
$("raw").addEventListener("change", () => showLayer(state.current));
document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "INPUT" && e.target.type !== "checkbox") return;
  if (e.key === "Escape") closeZoom();
  else if (e.key === "ArrowLeft") { setFollow(false); showLayer(state.current - 1); }
  else if (e.key === "ArrowRight") { setFollow(false); showLayer(state.current + 1); }
  else if (e.key === "End") { setFollow(true); if (state.newest) showLayer(state.newest); }
  else if (e.key === "Home") { setFollow(false); showLayer(1); }
  else if (e.key === "v") $("overlay").click();
  else if (e.key === "f") $("flags").click();
  else if (e.key === "r") $("raw").click();
  else if (e.key === "n") flagged(1);
  else if (e.key === "p") flagged(-1);
});

let refreshing = false, again = false;
async function refresh(status) {
  showStatus(status);
  if (refreshing) { again = true; return; }
  refreshing = true;
  try { await loadLayers(); } catch (e) { console.error(e); }
  refreshing = false;
  if (again) { again = false; refresh(null); }
}

const events = new EventSource("/api/events");
events.addEventListener("update", (e) => refresh(JSON.parse(e.data).status));
events.onerror = () => { $("state").textContent = "connection to the daemon lost; retrying"; };
const linked = layerFromHash();
if (linked) { setFollow(false); state.linked = linked; }
refresh(null);
getJson("/api/status").then(showStatus).catch(() => {});

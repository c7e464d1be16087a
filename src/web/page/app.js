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
  // Another build served at this address (a new build in the same folder, another `serve`):
  // what this page holds of the one before (its layers, vectors, pictures) goes with a reload.
  if (s.build_uid && state.buildUid && s.build_uid !== state.buildUid) { location.reload(); return; }
  if (s.build_uid) state.buildUid = s.build_uid;
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
  state.alarmLayer = s.alarm && s.alarm.state === "raised" ? s.alarm.layer : undefined;
  state.alarmAt = s.alarm && s.alarm.state === "raised" ? s.alarm.at : undefined;
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
    // The raise this page shows: refused if the alarm was raised again for another layer since.
    body: JSON.stringify({ by, note: $("ack-note").value, layer: state.alarmLayer, raised_at: state.alarmAt }),
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

// Deep links: #layer=N (the layer shown is always in the address, to copy and send), with
// &view=V to open that view large and &flag=K to mark the layer's flag K.
function layerFromHash() {
  const m = /(?:^#|&)layer=(\d{1,5})(?:&|$)/.exec(location.hash);
  return m ? Number(m[1]) : null;
}
function hashParam(key) {
  const m = new RegExp("(?:^#|&)" + key + "=([a-z_0-9]{1,32})(?:&|$)").exec(location.hash);
  return m ? m[1] : null;
}
window.addEventListener("hashchange", () => {
  const n = layerFromHash();
  if (n && (n !== state.current || hashParam("view") || hashParam("flag"))) { setFollow(false); showLayer(n, true); }
});

async function loadLayers() {
  const j = await getJson("/api/layers");
  // Following the build shows the newest layer with all its views; the one being captured is
  // a click (or End) away.
  const before = state.byLayer && JSON.stringify(state.byLayer.get(state.current));
  state.views = j.views; state.layers = j.layers; state.newest = j.complete || j.newest;
  state.expected = j.layers_expected; state.rectified = j.rectified; state.vectors = j.vectors; state.cropPx = j.crop_px; window.layerwiseCropPx = j.crop_px;
  state.byLayer = new Map(j.layers.map((l) => [l.layer, l]));
  // The layer shown changed (its frames processed, inspected, flagged): show it as it is now.
  const changed = before !== undefined && before !== JSON.stringify(state.byLayer.get(state.current));
  const slider = $("slider");
  const max = Math.max(1, j.newest || 1, ...j.layers.map((l) => l.layer));
  slider.max = max;
  drawTimeline();
  if (state.linked) { const n = state.linked; state.linked = null; showLayer(n, true); }
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

// What each kind of flag means, what to check and when to stop the build (the operator's card;
// docs/inspection.md says the same at length).
const GUIDE = {
  streak: ["a line along the recoater's path in the fresh powder: a worn or damaged recoater blade, or a part standing up that the blade caught",
    "the blade, and the parts on the line in the post-scan view", "stop when it persists over several layers across parts, or a part it crosses is also flagged"],
  short_feed: ["the new powder did not reach the end of the plate: too little powder dosed",
    "the dose factor and the powder left in the feed", "stop when parts lie in the bare band, or it repeats on the next layer"],
  coverage: ["a region of the fresh powder unlike the bed: uneven or thin powder, the layer below showing through, or something standing above it",
    "the region in the pre-scan views, and whether a part lies under it", "stop when it covers a part two layers running, or grows"],
  elevation: ["a part stands above the fresh powder (swelling, curling, super-elevation)",
    "the part's edge in the pre-scan views; the recoater may strike it", "stop before the recoater hits it: a critical elevation that persists"],
  under_fusion: ["the part fused less than its scan vectors say: the laser did not melt there",
    "the post-scan view against the vectors; the laser's power and the part's parameters", "stop when it is critical, or on two layers of the same part"],
  over_fusion: ["the part fused beyond its scan vectors' outline",
    "the part's contour in the post-scan view", "watch; stop if it grows layer after layer"],
  spatter: ["fused spots away from every part: spatter or a stray scan",
    "the spots in the post-scan view; the gas flow", "watch; stop if spots land on parts layer after layer"],
  drift: ["a part's metric moved away from its own running baseline (laser power, focus, powder)",
    "the part's trend; the same part on earlier layers", "stop when it keeps moving and the part is critical to you"],
  model: ["the trained model's class for this tile of the bed",
    "the tile's heat map (H) and the views under it; confirm or dismiss it to teach the model", "as the class's own kind says"],
};
function guide(kind) { const g = GUIDE[kind]; return g ? { means: g[0], check: g[1], stop: g[2] } : null; }

// The inspection flags of `view` as outlined boxes over a rectified picture, or over the crop
// `region` of it (fractions of the picture); null when there are none. Each box is numbered as
// the layer's flag list is, and its label says the kind and the score.
function flagBoxes(flags, view, region) {
  const r = region || { x: 0, y: 0, w: 1, h: 1 };
  const mine = (flags || []).map((f, i) => [f, i + 1]).filter(([f]) => f.box && f.draw_on.includes(view));
  if (!mine.length) return null;
  const layer = document.createElement("div");
  layer.className = "flags";
  for (const [f, number] of mine) {
    const b = document.createElement("div");
    b.className = "flag-box " + f.severity;
    b.dataset.kind = f.kind; b.dataset.flag = number;
    b.style.left = (100 * (f.box.x - r.x) / r.w) + "%";
    b.style.top = (100 * (f.box.y - r.y) / r.h) + "%";
    b.style.width = (100 * f.box.w / r.w) + "%";
    b.style.height = (100 * f.box.h / r.h) + "%";
    const g = guide(f.kind);
    b.title = f.message + " (score " + f.score.toFixed(2) + ", threshold " + f.threshold.toFixed(2) + ", " + f.severity + ")" + (g ? "\n" + g.means + "\ncheck: " + g.check + "\n" + g.stop : "");
    const t = document.createElement("span");
    t.textContent = (f.severity === "critical" ? "\u25b2 " : "") + number + " " + (f.class || f.kind) + " " + f.score.toFixed(1);
    b.append(t);
    layer.append(b);
  }
  return layer;
}

// Labels never overlap: within each flag layer, a label that would cover one placed before it
// (top to bottom, left to right) moves down below it. Run once the layer is on the page, and
// again when the page's size changes.
function declutter(root) {
  for (const layer of root.querySelectorAll(".flags")) {
    const labels = [...layer.querySelectorAll(".flag-box span")];
    labels.forEach((l) => { l.style.transform = ""; });
    const placed = [];
    const sorted = labels.map((l) => [l, l.getBoundingClientRect()]).sort((a, b) => a[1].top - b[1].top || a[1].left - b[1].left);
    for (const [l, r0] of sorted) {
      let dy = 0;
      for (let moved = true, rounds = 0; moved && rounds < 50; rounds++) {
        moved = false;
        for (const q of placed) {
          const top = r0.top + dy, bottom = r0.bottom + dy;
          if (r0.left < q.right && q.left < r0.right && top < q.bottom && q.top < bottom) { dy += q.bottom - top + 1; moved = true; }
        }
      }
      if (dy) l.style.transform = "translateY(" + dy + "px)";
      placed.push({ left: r0.left, right: r0.right, top: r0.top + dy, bottom: r0.bottom + dy });
    }
  }
}
function declutterSoon(root) { requestAnimationFrame(() => declutter(root)); }
window.addEventListener("resize", () => { declutter($("views")); declutter($("zoom")); });

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

async function showLayer(n, linked) {
  n = Math.max(1, Math.min(Number($("slider").max), n));
  state.current = n;
  // Only the newest call draws: one still waiting for an older answer gives up. A link's view
  // and flag stay wanted when a later call shows the same layer before the link's was drawn.
  const ticket = state.ticket = (state.ticket || 0) + 1;
  if (linked) state.want = { n, view: hashParam("view"), flag: hashParam("flag") };
  else if (state.want && state.want.n !== n) state.want = null;
  if (!linked && location.hash !== "#layer=" + n) history.replaceState(null, "", "#layer=" + n);
  $("layer-number").textContent = n;
  $("slider").value = n;
  document.querySelectorAll("#timeline .cell.current").forEach((c) => c.classList.remove("current"));
  const cell = document.querySelector('#timeline .cell[data-layer="' + n + '"]');
  if (cell) cell.classList.add("current");
  let detail;
  try { detail = await getJson("/api/layers/" + n); } catch (e) { detail = null; }
  if (ticket !== state.ticket) return;
  const svg = kind() === "rectified" ? await vectorsSvg(n) : "";
  if (ticket !== state.ticket) return;
  const want = state.want || {}; state.want = null;
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
  declutterSoon($("views"));
  const d = $("layer-detail"); d.replaceChildren();
  if (detail) {
    const s = detail.summary;
    dd(d, "frames", s.stored + " stored, " + s.missing + " missing");
    dd(d, "rectified", s.processed + (s.failed ? ", " + s.failed + " failed" : ""), s.failed ? "bad" : "ok");
    if (s.lag_ms != null) dd(d, "lag", s.lag_ms + " ms");
    for (const [phase, at] of Object.entries(detail.signals)) dd(d, phase + " signal", new Date(at).toLocaleTimeString());
    for (const f of detail.flags) dd(d, "flag", f, "wait");
    if (detail.bed) dd(d, "powder bed", Math.round(detail.bed.area_mm2) + " mm\u00b2 judged (settled at layer " + detail.bed.layer + ")");
    (detail.inspection || []).forEach((f, i) => flagEntry(d, n, f, i + 1));
  }
  if (detail && want.flag) document.querySelectorAll('[data-flag="' + want.flag + '"]').forEach((e) => e.classList.add("selected"));
  if (detail && want.view && detail.pictures[want.view]) openZoom(n, want.view, detail.pictures[want.view], detail.inspection, detail.bed, want.flag);
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
function flagEntry(dl, n, f, number) {
  const what = (f.class ? f.class + ": " : "") + f.message + " (" + f.severity + ", score " + f.score.toFixed(2) + ")";
  dd(dl, number + " " + f.kind, what, f.severity === "critical" ? "bad" : "wait");
  const d = dl.lastElementChild;
  d.dataset.flag = number; dl.lastElementChild.previousElementSibling.dataset.flag = number;
  const link = document.createElement("a");
  link.className = "flag-link"; link.textContent = "link"; link.title = "a link to this flag, to copy and send";
  link.href = "#layer=" + n + "&view=" + f.view + "&flag=" + number;
  d.append(" ", link);
  const g = guide(f.kind);
  if (g) {
    const more = document.createElement("details");
    more.className = "guide";
    const summary = document.createElement("summary"); summary.textContent = "what to do";
    more.append(summary);
    for (const [key, text] of [["means", g.means], ["check", g.check], ["stop", g.stop]]) {
      const p = document.createElement("p"); p.className = "guide-" + key;
      const b = document.createElement("b"); b.textContent = key === "means" ? "what it means: " : key === "check" ? "check: " : "when to stop: ";
      p.append(b, text); more.append(p);
    }
    d.append(more);
  }
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

// Zoom: the preview on the left; on the right a crop around the clicked point at full
// resolution (one pixel of the picture to one pixel of the screen, "1:1"), enlarged 2x, 4x or
// 8x with + and - (or the wheel) and moved by dragging it. A crop the server would scale down
// (wider than web.preview_px) or larger than the room beside the preview is halved until it is
// not; one that would fill a quarter of the room is doubled.
let zoomed = null;
async function openZoom(n, view, p, flags, bed, selected) {
  const z = zoomed = { n, view, p, kind: kind(), flags: flags || [], bed, crop: null, scale: 1 };
  $("zoom-title").textContent = "layer " + n + " " + view + " (" + zoomed.kind + ")";
  $("zoom-img").src = p[zoomed.kind];
  $("zoom-original").href = p.original;
  const svg = zoomed.kind === "rectified" ? await vectorsSvg(n) : "";
  // Closed (Escape) or another view opened while the vectors were on their way: not shown.
  if (zoomed !== z) return;
  $("zoom-vectors").innerHTML = svg;
  const boxes = zoomed.kind === "rectified" && flagBoxes(zoomed.flags, view);
  const outline = zoomed.kind === "rectified" && bedOutline(bed, view);
  $("zoom-flags").replaceChildren(...[outline, boxes].filter(Boolean));
  if (selected) $("zoom-flags").querySelectorAll('[data-flag="' + selected + '"]').forEach((e) => e.classList.add("selected"));
  $("zoom-crop-frame").hidden = true;
  $("zoom-scale").textContent = "";
  $("zoom").hidden = false;
  declutterSoon($("zoom-flags"));
}
function showCrop() {
  const c = zoomed.crop;
  c.x = Math.min(1 - c.w, Math.max(0, c.x)); c.y = Math.min(1 - c.h, Math.max(0, c.y));
  const q = { x: Number(c.x.toFixed(4)), y: Number(c.y.toFixed(4)), w: Number(c.w.toFixed(4)), h: Number(c.h.toFixed(4)) };
  $("zoom-crop").src = zoomed.p[zoomed.kind] + "&x=" + q.x + "&y=" + q.y + "&w=" + q.w + "&h=" + q.h;
  const boxes = zoomed.kind === "rectified" && flagBoxes(zoomed.flags, zoomed.view, q);
  const outline = zoomed.kind === "rectified" && bedOutline(zoomed.bed, zoomed.view, q);
  $("zoom-crop-flags").replaceChildren(...[outline, boxes].filter(Boolean));
  $("zoom-crop-frame").hidden = false;
}
$("zoom-crop").addEventListener("load", (e) => {
  const img = e.target;
  if (!zoomed || !zoomed.crop) return;
  const room = { w: window.innerWidth / 2 - 40, h: window.innerHeight - 90 };
  const scaledDown = img.naturalWidth >= (state.cropPx || 1024) || img.naturalHeight >= (state.cropPx || 1024);
  const tooLarge = img.naturalWidth * zoomed.scale > room.w || img.naturalHeight * zoomed.scale > room.h;
  if ((scaledDown || tooLarge) && zoomed.crop.w > 0.002) {
    // Scaled down by the server, or larger than the room beside the preview: a smaller crop
    // around the same center.
    const c = zoomed.crop; c.x += c.w / 4; c.y += c.h / 4; c.w /= 2; c.h /= 2;
    showCrop(); return;
  }
  const roomy = img.naturalWidth * zoomed.scale * 2 <= room.w && img.naturalHeight * zoomed.scale * 2 <= room.h;
  const small = img.naturalWidth * 2 < (state.cropPx || 1024) && img.naturalHeight * 2 < (state.cropPx || 1024);
  if (roomy && small && zoomed.crop.w < 1 && zoomed.crop.h < 1) {
    // A crop that would fill only a quarter of the room: twice as large around its center.
    const c = zoomed.crop, w = Math.min(1, c.w * 2), h = Math.min(1, c.h * 2);
    c.x -= (w - c.w) / 2; c.y -= (h - c.h) / 2; c.w = w; c.h = h;
    showCrop(); return;
  }
  img.style.width = img.naturalWidth * zoomed.scale + "px";
  img.style.height = img.naturalHeight * zoomed.scale + "px";
  img.dataset.scale = zoomed.scale;
  $("zoom-scale").textContent = zoomed.scale + ":1" + (zoomed.scale === 1 ? " (full resolution)" : "") + " · + / − or wheel to enlarge, drag to move";
  declutter($("zoom-crop-flags"));
});
$("zoom-img").addEventListener("click", (e) => {
  const r = e.target.getBoundingClientRect();
  const fx = (e.clientX - r.left) / r.width, fy = (e.clientY - r.top) / r.height;
  const w = 0.1, h = 0.1;
  zoomed.crop = { x: fx - w / 2, y: fy - h / 2, w, h };
  showCrop();
});
function zoomScale(factor) {
  if (!zoomed || !zoomed.crop) return;
  const next = Math.min(8, Math.max(1, zoomed.scale * factor));
  if (next === zoomed.scale) return;
  // The same center, the crop's share of the picture in proportion.
  const c = zoomed.crop, k = zoomed.scale / next;
  c.x += c.w * (1 - k) / 2; c.y += c.h * (1 - k) / 2; c.w *= k; c.h *= k;
  zoomed.scale = next;
  showCrop();
}
$("zoom-crop-frame").addEventListener("wheel", (e) => { e.preventDefault(); zoomScale(e.deltaY < 0 ? 2 : 0.5); }, { passive: false });
let dragging = null;
$("zoom-crop").addEventListener("pointerdown", (e) => { e.preventDefault(); dragging = { x: e.clientX, y: e.clientY }; });
window.addEventListener("pointerup", (e) => {
  if (!dragging || !zoomed || !zoomed.crop) { dragging = null; return; }
  const img = $("zoom-crop").getBoundingClientRect();
  const dx = (e.clientX - dragging.x) / img.width, dy = (e.clientY - dragging.y) / img.height;
  dragging = null;
  if (Math.abs(dx) + Math.abs(dy) < 0.005) return;
  zoomed.crop.x -= dx * zoomed.crop.w; zoomed.crop.y -= dy * zoomed.crop.h;
  showCrop();
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
  else if ((e.key === "+" || e.key === "=") && !$("zoom").hidden) zoomScale(2);
  else if (e.key === "-" && !$("zoom").hidden) zoomScale(0.5);
});

// Trends: a part's metrics over the layers, each beside the baseline band the drift check
// judged it against, the drifted layers marked; loaded when the panel is open, at most every 5 s
// while the build goes on.
let trends = null, trendsAt = 0;
async function loadTrends(force) {
  if (!$("trends").open || (!force && Date.now() - trendsAt < 5000)) return;
  trendsAt = Date.now();
  try { trends = await getJson("/api/trends"); } catch (e) { return; }
  const sel = $("trend-part"), keep = sel.value, parts = Object.keys(trends.parts);
  sel.replaceChildren(...parts.map((p) => new Option("part " + p, p)));
  const drifted = parts.find((p) => Object.values(trends.parts[p].series).some((s) => s.drift.length));
  sel.value = parts.includes(keep) ? keep : drifted || parts[0] || "";
  drawTrends();
}
function drawTrends() {
  const p = trends && trends.parts[$("trend-part").value];
  const box = $("trend-charts");
  if (!p) { box.textContent = "no part metrics yet (they need the inspection and a vector file)"; return; }
  box.replaceChildren(...trends.metrics.map((m) => trendChart(m, p.layers, p.series[m], trends.z)).filter(Boolean));
}
function trendChart(name, layers, s, z) {
  const at = (v) => v == null ? null : v;
  const lo = s.median.map((m, i) => m == null ? null : m - z * s.sigma[i]);
  const hi = s.median.map((m, i) => m == null ? null : m + z * s.sigma[i]);
  const ys = [...s.value, ...lo, ...hi].filter((v) => v != null);
  if (!s.value.some((v) => v != null)) return null;
  let y0 = Math.min(...ys), y1 = Math.max(...ys);
  if (y1 - y0 < 1e-9) { y0 -= 1; y1 += 1; }
  const W = 600, H = 130, L = 52, first = layers[0], last = layers[layers.length - 1];
  const x = (l) => (L + (W - L - 6) * (last > first ? (l - first) / (last - first) : 0.5)).toFixed(1);
  const y = (v) => (6 + (H - 24) * (1 - (v - y0) / (y1 - y0))).toFixed(1);
  // The band where a baseline exists, as one polygon per run of layers that have one.
  let band = "", run = [];
  const close = () => { if (run.length) band += '<polygon class="band" points="' + run.map((i) => x(layers[i]) + "," + y(hi[i])).concat(run.slice().reverse().map((i) => x(layers[i]) + "," + y(lo[i]))).join(" ") + '"/>'; run = []; };
  layers.forEach((_, i) => { if (hi[i] != null) run.push(i); else close(); });
  close();
  const line = (vals, cls) => {
    const pts = layers.map((l, i) => at(vals[i]) == null ? null : x(l) + "," + y(vals[i])).filter(Boolean);
    return pts.length ? '<polyline class="' + cls + '" points="' + pts.join(" ") + '"/>' : "";
  };
  const dots = s.drift.map((l) => { const i = layers.indexOf(l); return '<circle class="drift" r="3.5" cx="' + x(l) + '" cy="' + y(s.value[i]) + '"><title>layer ' + l + ": " + name + " " + s.value[i].toFixed(3) + " drifted</title></circle>"; }).join("");
  const now = state.current >= first && state.current <= last ? '<line class="now" x1="' + x(state.current) + '" x2="' + x(state.current) + '" y1="4" y2="' + (H - 18) + '"/>' : "";
  const fmt = (v) => Math.abs(v) >= 100 ? v.toFixed(0) : v.toPrecision(3);
  const div = document.createElement("div");
  div.className = "trend"; div.dataset.metric = name;
  div.innerHTML = '<svg viewBox="0 0 ' + W + " " + H + '" role="img" aria-label="' + name + '">' + band + line(s.median, "median") + line(s.value, "value") + dots + now +
    '<text x="4" y="14">' + fmt(y1) + '</text><text x="4" y="' + (H - 20) + '">' + fmt(y0) + '</text><text x="' + L + '" y="' + (H - 4) + '">' + name + " · layers " + first + "–" + last + "</text></svg>";
  return div;
}
$("trends").addEventListener("toggle", () => loadTrends(true));
$("trend-part").addEventListener("change", drawTrends);

let refreshing = false, again = false;
async function refresh(status) {
  showStatus(status);
  if (refreshing) { again = true; return; }
  refreshing = true;
  try { await loadLayers(); } catch (e) { console.error(e); }
  loadTrends(false);
  refreshing = false;
  if (again) { again = false; refresh(null); }
}

// The page server sends an update at least every 5 s (the status remade). A page that has heard
// nothing for STALE_MS is stale: a half-open connection (a laptop woken, Wi-Fi), a server that
// is stuck, or an event stream the browser closed for good (a refusal: 401, 503). It says so
// above everything it shows, with since when, and connects again; the first update clears it.
const STALE_MS = 15000;
let events = null, heard = Date.now(), connected = 0;
function connect() {
  if (events) events.close();
  connected = Date.now();
  events = new EventSource("/api/events");
  events.addEventListener("update", (e) => {
    heard = Date.now();
    $("stale").hidden = true;
    refresh(JSON.parse(e.data).status);
  });
  events.onerror = () => { $("state").textContent = "connection to the daemon lost; retrying"; };
}
// Why a stale page hears nothing, asked of the server beside the event stream (which says
// nothing of why it failed): no answer within 5 s, or its refusal with the server's reason.
let staleWhy = "", probing = false;
async function probeStale() {
  if (probing) return;
  probing = true;
  const abort = new AbortController(), timer = setTimeout(() => abort.abort(), 5000);
  try {
    const r = await fetch("/api/status", { credentials: "same-origin", cache: "no-store", signal: abort.signal });
    let reason = "";
    if (!r.ok) { try { reason = (await r.json()).error || ""; } catch (e) { reason = ""; } }
    staleWhy = r.ok ? "" : "The page server refuses this page (HTTP " + r.status + (reason ? ": " + reason.slice(0, 300) : "") + ").";
  } catch (e) {
    staleWhy = "The page server does not answer (stopped, stuck or out of reach).";
  } finally {
    clearTimeout(timer);
    probing = false;
  }
}
function watchStale() {
  const now = Date.now(), quiet = now - heard;
  if (quiet >= STALE_MS) {
    if (!probing && now - connected >= 5000) probeStale();
    $("stale").textContent = "STALE: nothing heard from the page server since " + new Date(heard).toLocaleTimeString() +
      " (" + Math.round(quiet / 1000) + " s); what this page shows may be out of date. " + (staleWhy ? staleWhy + " " : "") + "Reconnecting\u2026";
    $("stale").hidden = false;
  } else staleWhy = "";
  const closed = events.readyState === EventSource.CLOSED;
  if ((closed && now - connected >= 5000) || (quiet >= STALE_MS && now - connected >= STALE_MS)) connect();
}
connect();
setInterval(watchStale, 1000);
const linked = layerFromHash();
if (linked) { setFollow(false); state.linked = linked; }
refresh(null);
getJson("/api/status").then(showStatus).catch(() => {});

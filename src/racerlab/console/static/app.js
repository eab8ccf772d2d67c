// racerlab console: one page, hash routes, no framework. Every piece of text from the server goes into the
// page as text (el(...) / textContent), never as HTML.
"use strict";

const CSRF = document.querySelector('meta[name="csrf-token"]').content;
const main = document.getElementById("main");
let cleanups = [];  // event sources and timers of the current view

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else if (k === "text") node.textContent = v;
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) node.append(c instanceof Node ? c : String(c));
  return node;
}
const svgNS = "http://www.w3.org/2000/svg";
function svg(tag, attrs) {
  const node = document.createElementNS(svgNS, tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "text") node.textContent = v; else node.setAttribute(k, v);
  }
  return node;
}

async function api(method, url, body, isForm) {
  const opts = { method, headers: { "X-CSRF-Token": CSRF } };
  if (body !== undefined) {
    if (isForm) opts.body = body;
    else { opts.body = JSON.stringify(body); opts.headers["Content-Type"] = "application/json"; }
  }
  const resp = await fetch(url, opts);
  const data = await resp.json().catch(() => ({}));
  if (!resp.ok) throw new Error(data.error || (data.detail && JSON.stringify(data.detail)) || resp.statusText);
  return data;
}

function toast(message, isError) {
  const box = el("div", { class: isError ? "error" : "", text: message });
  document.getElementById("toast").append(box);
  setTimeout(() => box.remove(), isError ? 9000 : 4000);
}
async function guarded(fn) {
  try { return await fn(); } catch (e) { toast(e.message, true); return null; }
}
const fmt = (x, d = 2) => (x === null || x === undefined || Number.isNaN(x)) ? "–" : Number(x).toFixed(d);

async function pollTask(key, onDone) {
  for (;;) {
    await new Promise(r => setTimeout(r, 700));
    const t = await guarded(() => api("GET", "/api/tasks/" + encodeURIComponent(key)));
    if (!t) return;
    if (t.status !== "running") {
      if (t.status === "failed") toast(t.message, true);
      onDone(t);
      return;
    }
  }
}

// ---- routing --------------------------------------------------------------------------------------------
const routes = { models: viewModels, new: viewNew, model: viewModel, races: viewRaces, analysis: viewAnalysis,
                 exchange: viewExchange };
function route() {
  cleanups.forEach(f => f()); cleanups = [];
  const parts = (location.hash.replace(/^#\/?/, "") || "models").split("/").map(decodeURIComponent);
  document.querySelectorAll("header nav a").forEach(a => a.classList.toggle("active", a.dataset.nav === parts[0]));
  main.replaceChildren();
  (routes[parts[0]] || viewModels)(...parts.slice(1));
}
window.addEventListener("hashchange", route);
window.addEventListener("DOMContentLoaded", route);

// ---- models list ------------------------------------------------------------------------------------------
async function viewModels() {
  const data = await guarded(() => api("GET", "/api/models"));
  if (!data) return;
  document.getElementById("workspace").textContent = data.workspace;
  const rows = data.models.map(m => el("tr", { "data-model": m.name },
    el("td", {}, el("a", { href: "#/model/" + encodeURIComponent(m.name), text: m.name })),
    el("td", {}, el("span", { class: "badge " + m.state, text: m.state })),
    el("td", { text: (m.track || []).join(", ") }),
    el("td", { text: (m.sensor || []).join(" + ") }),
    el("td", { text: m.algorithm || "" }),
    el("td", { text: bestLap(m) }),
    el("td", { text: String(m.iteration) }),
    el("td", { class: "muted error", text: m.error || (m.folder !== m.name ? "in " + m.folder : "") })));
  main.append(el("h1", { text: "Models" }),
    el("div", { class: "card tablecard", id: "models-card" }, rows.length ? el("table", { id: "models-table" },
      el("tr", {}, ...["model", "state", "track", "sensor", "algorithm", BEST_LAP, "iteration", ""].map(h => el("th", { text: h }))),
      ...rows) : el("p", { class: "muted", text: "No models in this workspace yet: create one under New model." })),
    el("p", {}, el("button", { onclick: () => { location.hash = "#/new"; }, text: "New model" })));
  const timer = setInterval(async () => {
    const fresh = await api("GET", "/api/models").catch(() => null);
    if (!fresh) return;
    for (const m of fresh.models) {
      const row = main.querySelector(`tr[data-model="${CSS.escape(m.name)}"]`);
      if (!row) continue;
      const badge = row.querySelector(".badge");
      if (badge.textContent !== m.state) { badge.textContent = m.state; badge.className = "badge " + m.state; }
      row.children[5].textContent = bestLap(m); row.children[6].textContent = String(m.iteration);
    }
  }, 3000);
  cleanups.push(() => clearInterval(timer));
}

// ---- the wizard ---------------------------------------------------------------------------------------------
async function viewNew() {
  const [tracks, defaults] = await Promise.all([api("GET", "/api/tracks"), api("GET", "/api/defaults")]);
  const state = { track: tracks.tracks.includes("lab_technical") ? "lab_technical" : tracks.tracks[0],
                  actions: defaults.metadata.action_space };
  const name = el("input", { id: "new-name", placeholder: "my-model", pattern: "[A-Za-z0-9][A-Za-z0-9._-]*" });
  const sensor = el("select", { id: "new-sensor" }, ...defaults.sensors.map(s => el("option", { value: s, text: s })));
  const space = el("select", { id: "new-space" }, el("option", { text: "discrete" }), el("option", { text: "continuous" }));
  const algo = el("select", { id: "new-algo" }, el("option", { text: "clipped_ppo" }), el("option", { text: "sac" }));
  const speed = el("input", { id: "new-speed", type: "number", step: "0.1", min: "0.1", max: "4", value: "1" });
  const cars = el("input", { id: "new-cars", type: "number", min: "1", value: "" , placeholder: "32" });
  const search = el("input", { id: "track-search", class: "tracksearch", type: "search", placeholder: `search ${tracks.tracks.length} tracks`,
    oninput: () => { const q = search.value.trim().toLowerCase();
      picker.querySelectorAll(".trackpick").forEach(p => { p.style.display = !q || p.dataset.track.toLowerCase().includes(q) ? "" : "none"; }); } });
  const picker = el("div", { class: "tracks" }, ...tracks.tracks.map(t => el("div", {
    class: "trackpick" + (t === state.track ? " selected" : ""), "data-track": t,
    onclick: (ev) => { state.track = t; picker.querySelectorAll(".trackpick").forEach(p => p.classList.toggle("selected", p.dataset.track === t)); } },
    el("img", { src: "/api/tracks/" + encodeURIComponent(t) + ".svg", loading: "lazy", alt: t }), el("div", { text: t }))));
  const actionsBox = el("div");
  const fan = el("div", { class: "actions-fan" });
  const reward = el("textarea", { id: "new-reward", rows: "16" }); reward.value = defaults.reward;
  const checkOut = el("div");
  const hpRows = Object.entries(defaults.hyperparameters).map(([k, v]) => el("tr", {},
    el("td", { text: k }), el("td", {}, el("input", { "data-hp": k, value: String(v) })),
    el("td", { class: "muted", text: defaults.help[k] || "" })));

  async function reloadDefaults() {
    const q = new URLSearchParams({ sensor: sensor.value, action_space: space.value, algorithm: algo.value, max_speed: speed.value });
    const d = await guarded(() => api("GET", "/api/defaults?" + q));
    if (d) { state.actions = d.metadata.action_space; drawActions(); }
  }
  function drawActions() {
    actionsBox.replaceChildren(); fan.replaceChildren();
    if (Array.isArray(state.actions)) {
      const rows = state.actions.map((a, i) => el("tr", {},
        el("td", { text: String(i) }),
        el("td", {}, el("input", { type: "number", step: "1", value: String(a.steering_angle), oninput: (e) => { a.steering_angle = Number(e.target.value); drawFan(); } })),
        el("td", {}, el("input", { type: "number", step: "0.1", value: String(a.speed), oninput: (e) => { a.speed = Number(e.target.value); drawFan(); } })),
        el("td", {}, el("button", { class: "secondary", text: "remove", onclick: () => { state.actions.splice(i, 1); drawActions(); } }))));
      actionsBox.append(el("table", { id: "actions-table" }, el("tr", {}, el("th", { text: "#" }), el("th", { text: "steering (°)" }), el("th", { text: "speed (m/s)" }), el("th")), ...rows),
        el("button", { class: "secondary", text: "add action", onclick: () => { state.actions.push({ steering_angle: 0, speed: 1 }); drawActions(); } }));
    } else {
      for (const [k, v] of Object.entries(state.actions)) {
        for (const [b, x] of Object.entries(v)) {
          actionsBox.append(el("label", {}, `${k} ${b} `, el("input", { type: "number", step: "0.1", value: String(x), oninput: (e) => { v[b] = Number(e.target.value); drawFan(); } })), " ");
        }
      }
    }
    drawFan();
  }
  function drawFan() {
    // each action as a ray from the car: the angle is the steering (left is left), the length the speed
    const s = svg("svg", { viewBox: "-150 -160 300 170" });
    s.append(svg("circle", { cx: 0, cy: 0, r: 4, fill: "#1d232b" }));
    const pairs = Array.isArray(state.actions) ? state.actions.map(a => [a.steering_angle, a.speed])
      : [[state.actions.steering_angle.low, state.actions.speed.high], [state.actions.steering_angle.high, state.actions.speed.high],
         [state.actions.steering_angle.low, state.actions.speed.low], [state.actions.steering_angle.high, state.actions.speed.low]];
    const top = Math.max(...pairs.map(p => p[1]), 0.1);
    const placed = [];  // label boxes already drawn: a label that would overlap one moves out along its ray, or is left out
    for (const [deg, v] of pairs) {
      const r = 110 * v / top, a = (deg * Math.PI) / 180;
      const x = -r * Math.sin(a), y = -r * Math.cos(a);
      const line = svg("line", { x1: 0, y1: 0, x2: x, y2: y, stroke: "#e4572e", "stroke-width": 2 });
      line.append(svg("title", { text: `steering ${deg}°, speed ${v} m/s` }));
      s.append(line);
      const text = `${deg}°/${v}`, w = 5.2 * text.length, h = 10;
      for (let k = 0; k < 4; k++) {
        const rr = r + 8 + 11 * k, lx = -rr * Math.sin(a), ly = -rr * Math.cos(a);
        const box = [lx - w / 2, ly - h / 2, lx + w / 2, ly + h / 2];
        if (placed.some(b => box[0] < b[2] && b[0] < box[2] && box[1] < b[3] && b[1] < box[3])) continue;
        placed.push(box);
        s.append(svg("text", { x: lx, y: ly + 3, "font-size": 9, "text-anchor": "middle", class: "fan-label", text }));
        break;
      }
    }
    fan.replaceChildren(s);
  }
  [sensor, space, algo, speed].forEach(x => x.addEventListener("change", reloadDefaults));
  drawActions();

  const check = el("button", { class: "secondary", id: "reward-check", text: "Check reward", onclick: async () => {
    check.disabled = true;
    const r = await guarded(() => api("POST", "/api/reward/check", { reward: reward.value, track: state.track }));
    check.disabled = false;
    if (r) checkOut.replaceChildren(el("p", { text: r.ok ? "reward check: no problems" : "reward check: PROBLEMS found" }),
      el("pre", { id: "reward-report", text: r.report }), el("img", { src: r.map, alt: "reward map", style: "max-width:100%" }));
  } });
  const create = el("button", { id: "new-create", text: "Create model", onclick: async () => {
    const hp = {};
    main.querySelectorAll("input[data-hp]").forEach(i => { hp[i.dataset.hp] = i.value; });
    const body = { name: name.value.trim(), track: state.track, sensor: sensor.value, action_space: space.value,
                   algorithm: algo.value, max_speed: Number(speed.value), actions: state.actions, reward: reward.value,
                   hyperparameters: hp, cars: cars.value ? Number(cars.value) : null };
    const m = await guarded(() => api("POST", "/api/models", body));
    if (m) { toast("created " + m.name); location.hash = "#/model/" + encodeURIComponent(m.name); }
  } });
  main.append(el("h1", { text: "New model" }),
    el("div", { class: "card" }, el("div", { class: "form" },
      el("label", { text: "Name" }), name, el("label", { text: "Sensor" }), sensor,
      el("label", { text: "Action space" }), space, el("label", { text: "Algorithm" }), algo,
      el("label", { text: "Top speed (m/s)" }), speed, el("label", { text: "Cars in parallel" }), cars)),
    el("div", { class: "card" }, el("h2", { text: "Track" }), search, picker),
    el("div", { class: "card row" }, el("div", {}, el("h2", { text: "Action space" }), actionsBox), el("div", {}, el("h3", { text: "speed / steering pairs" }), fan)),
    el("div", { class: "card" }, el("h2", { text: "Reward function" }), reward, el("p", {}, check), checkOut),
    el("div", { class: "card" }, el("h2", { text: "Hyperparameters" }), el("table", {}, ...hpRows)),
    el("p", {}, create));
}

// ---- charts ------------------------------------------------------------------------------------------------
const CHARTS = [
  { id: "reward", title: "mean reward per episode", series: [["charts/mean_reward", "#e4572e"]] },
  { id: "progress", title: "progress %: training (orange), evaluation (blue)", series: [["charts/completion", "#f3a712"], ["eval/mean_progress", "#4c9be8"]] },
  { id: "entropy", title: "policy entropy", series: [["losses/entropy", "#7b4fd6"]] },
  { id: "laps", title: "evaluation lap time, s: this iteration (dots), best (line)", series: [["eval/best_lap", "#2e8b57", true], ["best/lap_time", "#1d232b"]] },
];
function drawChart(box, spec, points) {
  const W = 300, H = 170, L = 40, B = 20, T = 8, R = 8;
  const s = svg("svg", { viewBox: `0 0 ${W} ${H}`, id: "chart-" + spec.id, "data-points": points.length });
  const xs = points.map(p => p.iteration);
  const ys = spec.series.flatMap(([k]) => points.map(p => p[k]).filter(v => v !== null && v !== undefined));
  if (!points.length || !ys.length) {
    s.append(svg("text", { x: W / 2, y: H / 2, "text-anchor": "middle", fill: "#6b7480", "font-size": 12, text: "no data yet" }));
    box.replaceChildren(el("div", { class: "title", text: spec.title }), s); return;
  }
  let x0 = Math.min(...xs), x1 = Math.max(...xs); if (x1 === x0) { x0 -= 1; x1 += 1; }
  let y0 = Math.min(...ys), y1 = Math.max(...ys); if (y1 === y0) { y0 -= 1; y1 += 1; }
  const X = x => L + (x - x0) / (x1 - x0) * (W - L - R), Y = y => T + (1 - (y - y0) / (y1 - y0)) * (H - T - B);
  s.append(svg("line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "#999" }), svg("line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "#999" }));
  for (const [v, y] of [[y1, T + 8], [y0, H - B]]) s.append(svg("text", { x: L - 3, y, "text-anchor": "end", "font-size": 9, fill: "#555", text: fmt(v, Math.abs(v) < 10 ? 2 : 0) }));
  s.append(svg("text", { x: L, y: H - 5, "font-size": 9, fill: "#555", text: String(x0) }),
           svg("text", { x: W - R, y: H - 5, "font-size": 9, fill: "#555", "text-anchor": "end", text: "iteration " + x1 }));
  for (const [key, color, dots] of spec.series) {
    const pts = points.filter(p => p[key] !== null && p[key] !== undefined);
    if (!dots && pts.length > 1) s.append(svg("polyline", { points: pts.map(p => `${X(p.iteration).toFixed(1)},${Y(p[key]).toFixed(1)}`).join(" "), fill: "none", stroke: color, "stroke-width": 1.5 }));
    if (dots || pts.length <= 60) for (const p of pts) s.append(svg("circle", { cx: X(p.iteration), cy: Y(p[key]), r: 2.2, fill: color }));
  }
  box.replaceChildren(el("div", { class: "title", text: spec.title }), s);
}

// ---- one model ---------------------------------------------------------------------------------------------
async function viewModel(name, tab) {
  tab = tab || "training";
  const m = await guarded(() => api("GET", "/api/models/" + encodeURIComponent(name)));
  if (!m) return;
  const base = "#/model/" + encodeURIComponent(name) + "/";
  const badge = el("span", { class: "badge " + m.state, id: "model-state", text: m.state });
  const tabs = el("div", { class: "tabs" }, ...["training", "evaluation", "analysis", "files", "exchange"].map(t =>
    el("a", { href: base + t, class: t === tab ? "active" : "", text: t })));
  const clone = el("button", { class: "secondary", text: "Clone", onclick: async () => {
    const dst = prompt(`Clone ${name} (best checkpoint) as:`, name + "-clone");
    if (!dst) return;
    const c = await guarded(() => api("POST", `/api/models/${encodeURIComponent(name)}/clone`, { name: dst }));
    if (c) location.hash = "#/model/" + encodeURIComponent(c.name);
  } });
  const del = el("button", { class: "danger", text: "Delete", onclick: async () => {
    const typed = prompt(`Delete ${name} and all its checkpoints and logs? Type its name to confirm.`);
    if (typed !== name) { if (typed !== null) toast("name did not match: nothing deleted", true); return; }
    const r = await guarded(() => api("DELETE", `/api/models/${encodeURIComponent(name)}?confirm=${encodeURIComponent(typed)}`));
    if (r) { toast("deleted " + name); location.hash = "#/models"; }
  } });
  const header = el("p", { class: "muted", id: "model-header", text: headerText(m) });
  main.append(el("h1", {}, name + " ", badge), header, el("p", {}, clone, " ", del), tabs);
  const body = el("div"); main.append(body);
  ({ training: tabTraining, evaluation: tabEvaluation, analysis: tabAnalysis, files: tabFiles, exchange: tabExchange }[tab] || tabTraining)(body, m, badge, header);
}

// "best lap" means one thing on every surface: the best eval lap (racerlab.logs.BEST_LAP_MEANING)
const BEST_LAP = "best eval lap";
function bestLap(m) {
  if (m.best_lap === null || m.best_lap === undefined) return "–";
  return fmt(m.best_lap, 3) + " s" + (m.best_lap_iteration ? ` (it. ${m.best_lap_iteration})` : "");
}
function headerText(m) {
  const best = m.best_checkpoint ? ` · best checkpoint ${m.best_checkpoint}` + (m.best_rule ? ` (${m.best_rule})` : "") : "";
  return `${(m.sensor || []).join(" + ")} · ${m.algorithm} · ${m.action_space} · track ${(m.track || []).join(", ")} · ` +
    `iteration ${m.iteration} · ${BEST_LAP} ${bestLap(m)}${best}`;
}

function setState(badge, state, controls) {
  badge.textContent = state; badge.className = "badge " + state;
  if (controls) controls(state);
}

function tabTraining(body, m, badge, header) {
  const name = m.name;
  const minutes = el("input", { id: "train-minutes", type: "number", step: "0.5", min: "0", placeholder: "min" });
  const episodes = el("input", { id: "train-episodes", type: "number", min: "1", placeholder: "episodes" });
  const iterations = el("input", { id: "train-iterations", type: "number", min: "1", placeholder: "iterations" });
  const start = el("button", { id: "train-start", text: m.iteration > 0 ? "Resume training" : "Start training", onclick: async () => {
    const r = await guarded(() => api("POST", `/api/models/${encodeURIComponent(name)}/train`,
      { minutes: minutes.value || null, episodes: episodes.value || null, iterations: iterations.value || null }));
    if (r) setState(badge, "training", controls);
  } });
  const stop = el("button", { id: "train-stop", class: "secondary", text: "Stop (saves)", onclick: async () => {
    const r = await guarded(() => api("POST", `/api/models/${encodeURIComponent(name)}/stop`));
    if (r) toast("stopping: the last complete iteration is kept");
  } });
  let state = m.state;
  const label = () => { start.textContent = state === "training" ? "Training…" : m.iteration > 0 ? "Resume training" : "Start training"; };
  const controls = (now) => {
    state = now; start.disabled = now !== "idle"; stop.disabled = now !== "training"; label();
    if (now === "idle") { refreshLog(); refreshHeader(); }
  };
  async function refreshHeader() {  // after a stop: the iteration and best lap the training ended with
    const fresh = await api("GET", `/api/models/${encodeURIComponent(name)}`).catch(() => null);
    if (fresh) { Object.assign(m, fresh); header.textContent = headerText(m); label(); }
  }
  controls(m.state);
  const charts = el("div", { class: "charts" }); const boxes = {};
  for (const c of CHARTS) { boxes[c.id] = el("div", { class: "chart" }); charts.append(boxes[c.id]); }
  const logBox = el("pre", { id: "train-log", text: m.log || "(no training started from the console yet)" });
  async function refreshLog() { const l = await api("GET", `/api/models/${encodeURIComponent(name)}/log`).catch(() => null); if (l) logBox.textContent = l.log; }
  body.append(el("div", { class: "card" }, el("span", { text: "Stop after " }), minutes, " min ", episodes, " episodes ", iterations,
      " iterations (empty: training.toml / hyperparameters) ", start, " ", stop),
    charts, el("h2", { text: "Live view" }), liveView(name), el("h2", { text: "Training output" }), logBox);

  let points = [];
  window.__chartPoints = [];
  const redraw = () => CHARTS.forEach(c => drawChart(boxes[c.id], c, points));
  const es = new EventSource(`/api/models/${encodeURIComponent(name)}/events`);
  es.addEventListener("history", (e) => { const d = JSON.parse(e.data); points = d.points; setState(badge, d.state, controls); redraw(); });
  es.addEventListener("point", (e) => {
    const p = JSON.parse(e.data); points.push(p); redraw();
    m.iteration = p.iteration;
    if (p["best/lap_time"] !== null && p["best/lap_time"] !== undefined) { m.best_lap = p["best/lap_time"]; m.best_lap_iteration = p["best/lap_iteration"]; }
    if (p["best/checkpoint"]) m.best_checkpoint = p["best/checkpoint"];
    header.textContent = headerText(m);
    window.__chartPoints.push({ iteration: p.iteration, time: p.time, shown: Date.now() / 1000 });
    refreshLog();
  });
  es.addEventListener("state", (e) => setState(badge, JSON.parse(e.data).state, controls));
  cleanups.push(() => es.close());
}

function liveView(name) {
  const wrap = el("div", { class: "live card", id: "live" });
  const info = el("div", { class: "muted", text: "waiting for the first logged iteration…" });
  const carSel = el("input", { type: "number", min: "0", value: "0", title: "car shown on the right" });
  const img = el("img", { alt: "track" });
  const canvas = el("canvas");
  const cam = el("img", { id: "live-camera", alt: "camera", width: 320, height: 240, style: "image-rendering:pixelated;background:#222" });
  const lidar = el("canvas", { width: 160, height: 160, style: "background:#fafbfc;border:1px solid #d9dde3" });
  const sensesText = el("div", { id: "live-sees" });
  wrap.append(el("div", { class: "map" }, img, canvas),
    el("div", { class: "sees" }, el("div", {}, "car ", carSel, " ", sensesText), cam, lidar, info));
  function showPanels(sees) {  // only what the model sees: a features model sees a vector, not a picture
    cam.style.display = sees.includes("camera") ? "" : "none";
    lidar.style.display = sees.includes("lidar") ? "" : "none";
    sensesText.textContent = sees.length ? sees.map(s => s === "camera" ? "camera (160×120, as the model sees it)" : "lidar").join(" and ")
      : "this model sees a features vector (speed, steering, offsets, the centre line ahead): no camera or lidar to show";
  }
  let frame = null, es = null, running = true, shown = 0;
  const track = fetch(`/api/models/${encodeURIComponent(name)}`).then(r => r.json()).then(async m => {
    const t = (m.track || [])[0];
    const text = await (await fetch(`/api/tracks/${encodeURIComponent(t)}.svg`)).text();
    const doc = new DOMParser().parseFromString(text, "image/svg+xml").documentElement;
    frame = { x0: +doc.dataset.x0 || +doc.getAttribute("data-x0"), y1: +doc.getAttribute("data-y1"), scale: +doc.getAttribute("data-scale"),
              w: +doc.getAttribute("width"), h: +doc.getAttribute("height") };
    img.src = `/api/tracks/${encodeURIComponent(t)}.svg`; canvas.width = frame.w; canvas.height = frame.h;
  }).catch(() => {});
  function connect() {
    if (es) es.close();
    es = new EventSource(`/api/models/${encodeURIComponent(name)}/live?car=${Number(carSel.value) || 0}`);
    es.addEventListener("view", (e) => {
      const d = JSON.parse(e.data);
      info.textContent = `replaying iteration ${d.iteration} (logged simtrace), step ${d.step}, ${d.cars.length} cars`;
      if (d.car !== undefined) shown = d.car;
      if (frame) {
        const g = canvas.getContext("2d"); g.clearRect(0, 0, canvas.width, canvas.height);
        d.cars.forEach((c, i) => {
          const x = (c[0] - frame.x0) * frame.scale, y = (frame.y1 - c[1]) * frame.scale, a = -c[2] * Math.PI / 180;
          g.save(); g.translate(x, y); g.rotate(a); g.fillStyle = i === shown ? "#e4572e" : "#4c9be8";
          g.fillRect(-5, -3, 10, 6); g.restore();
        });
      }
      if (d.sees) showPanels(d.sees);
      if (d.camera) cam.src = d.camera;
      if (d.lidar) drawLidar(lidar, d.lidar, d.angles);
    });
    es.addEventListener("waiting", (e) => { info.textContent = JSON.parse(e.data).message; });
  }
  carSel.addEventListener("change", connect);
  track.then(() => { if (running) connect(); });
  cleanups.push(() => { running = false; if (es) es.close(); });
  return wrap;
}

function drawLidar(canvas, ranges, angles) {
  // the scan in the car's frame, ahead up and left to the left; the circle is the 1 m range
  const g = canvas.getContext("2d"), c = 80, s = 70;
  g.clearRect(0, 0, 160, 160);
  g.strokeStyle = "#ccc"; g.beginPath(); g.arc(c, c, s, 0, 2 * Math.PI); g.stroke();
  g.fillStyle = "#e4572e";
  ranges.forEach((r, i) => {
    const a = angles[i], d = Math.min(r, 1) * s;
    g.fillRect(c - Math.sin(a) * d - 1, c - Math.cos(a) * d - 1, 2, 2);
  });
  g.fillStyle = "#1d232b"; g.fillRect(c - 3, c - 5, 6, 10);
}

function lapTable(laps) {
  return el("table", {}, el("tr", {}, ...["lap", "time (s)", "status", "progress", "off-track", "resets"].map(h => el("th", { text: h }))),
    ...laps.map(l => el("tr", {}, el("td", { text: String(l.trial) }), el("td", { text: fmt(l.elapsed, 3) }), el("td", { text: l.status }),
      el("td", { text: fmt(l.progress, 1) + " %" }), el("td", { text: String(l.off_track) }), el("td", { text: String(l.resets) }))));
}

function rulesForm(prefix) {
  const f = {
    track: el("input", { id: prefix + "-track", placeholder: "training track" }),
    trials: el("input", { id: prefix + "-trials", type: "number", min: "1", value: "3" }),
    continuous: el("input", { type: "checkbox", checked: true }),
    off_track_penalty: el("input", { type: "number", step: "0.5", value: "5" }),
    collision_penalty: el("input", { type: "number", step: "0.5", value: "5" }),
    max_resets: el("input", { type: "number", value: "100" }),
    reverse: el("input", { type: "checkbox" }),
  };
  const grid = el("div", { class: "form" },
    el("label", { text: "Track (empty: the training track)" }), f.track, el("label", { text: "Laps / trials" }), f.trials,
    el("label", { text: "Continuous laps" }), f.continuous, el("label", { text: "Off-track penalty (s)" }), f.off_track_penalty,
    el("label", { text: "Collision penalty (s)" }), f.collision_penalty, el("label", { text: "Resets allowed" }), f.max_resets,
    el("label", { text: "Reverse direction" }), f.reverse);
  const values = () => ({ track: f.track.value.trim() || null, trials: Number(f.trials.value), continuous: f.continuous.checked,
    off_track_penalty: Number(f.off_track_penalty.value), collision_penalty: Number(f.collision_penalty.value),
    max_resets: Number(f.max_resets.value), reverse: f.reverse.checked });
  return { grid, values };
}

async function tabEvaluation(body, m) {
  const name = m.name;
  const rules = rulesForm("eval");
  const checkpoint = el("input", { id: "eval-checkpoint", value: "best" });
  const video = el("input", { id: "eval-video", type: "checkbox", checked: true });
  const list = el("div");
  const go = el("button", { id: "eval-start", text: "Run evaluation", onclick: async () => {
    const t = await guarded(() => api("POST", `/api/models/${encodeURIComponent(name)}/evaluate`,
      { ...rules.values(), checkpoint: checkpoint.value, video: video.checked }));
    if (!t) return;
    go.disabled = true; toast("evaluating…");
    pollTask(t.key, () => { go.disabled = false; refresh(); });
  } });
  rules.grid.append(el("label", { text: "Checkpoint" }), checkpoint, el("label", { text: "Video (MP4)" }), video);
  body.append(el("div", { class: "card" }, rules.grid, el("p", {}, go)), list);
  async function refresh() {
    const d = await guarded(() => api("GET", `/api/models/${encodeURIComponent(name)}/evaluations`));
    if (!d) return;
    list.replaceChildren(...d.evaluations.map(ev => {
      const s = ev.summary;
      const card = el("div", { class: "card evaluation", "data-evaluation": ev.name }, el("h3", { text: ev.name }));
      if (s) card.append(el("p", { text: `${s.track} · checkpoint ${s.checkpoint} · ${s.result.text}` }), lapTable(s.laps));
      if (ev.video) card.append(el("video", { controls: true, preload: "metadata", width: 640,
        src: `/api/models/${encodeURIComponent(name)}/evaluations/${encodeURIComponent(ev.name)}/video` }));
      return card;
    }));
    if (!d.evaluations.length) list.append(el("p", { class: "muted", text: "No evaluations yet." }));
  }
  refresh();
}

function reportFrame(url) { return el("iframe", { src: url, sandbox: "allow-popups", title: "report" }); }

function tabAnalysis(body, m) {
  const name = m.name;
  const url = `/api/models/${encodeURIComponent(name)}/report`;
  const holder = el("div");
  const make = el("button", { id: "report-make", text: "Make report", onclick: async () => {
    const t = await guarded(() => api("POST", url)); if (!t) return;
    make.disabled = true; toast("writing the report…");
    pollTask(t.key, (done) => { make.disabled = false; if (done.status === "done") holder.replaceChildren(reportFrame(url + "?t=" + Date.now())); });
  } });
  body.append(el("div", { class: "card" }, el("p", { text: "The HTML report (racerlab report): training progress, lap times, heatmaps, paths, actions." }), make), holder);
  fetch(url, { method: "HEAD" }).then(r => { if (r.ok) holder.replaceChildren(reportFrame(url)); });
}

function tabFiles(body, m) {
  for (const [file, text] of Object.entries(m.files)) {
    body.append(el("div", { class: "card" }, el("h3", { text: file }), el("pre", { text: text === null ? "(missing)" : text })));
  }
  body.append(el("div", { class: "card" }, el("h3", { text: "checkpoints" }), el("pre", { text: m.checkpoints.join("\n") || "(none)" })));
}

// ---- exchange: exports for the car / DeepRacer-on-AWS / DRfC, import of their archives ------------------------
async function tabExchange(body, m) {
  const x = await api("GET", "/api/exchange");
  const base = `/api/models/${encodeURIComponent(m.name)}/exports`;
  const files = el("div", { id: "export-files" });
  const refresh = async () => {
    const d = await guarded(() => api("GET", base)); if (!d) return;
    files.replaceChildren(...(d.exports.length ? d.exports.map(e => el("p", {},
      el("a", { href: `${base}/${encodeURIComponent(e.name)}`, download: e.name, text: e.name }),
      el("span", { text: ` (${(e.bytes / 1e6).toFixed(2)} MB)` }))) : [el("p", { class: "muted", text: "No exports yet." })]));
  };
  const status = el("p", { id: "export-status", class: "muted" });
  const buttons = x.exports.map(e => el("button", { id: "export-" + e.kind, text: e.label, onclick: async (ev) => {
    const b = ev.currentTarget; b.disabled = true; status.textContent = e.label + "…";
    const t = await guarded(() => api("POST", `/api/models/${encodeURIComponent(m.name)}/export/${e.kind}`));
    if (!t) { b.disabled = false; status.textContent = ""; return; }
    pollTask(t.key, (done) => {
      b.disabled = false;
      status.textContent = done.status === "done" ? `${done.result.archive} written.` : done.message;
      refresh();
    });
  } }));
  body.append(el("div", { class: "card", id: "exchange" }, el("h2", { text: "Export" }),
    el("p", { text: "The car takes model_metadata.json and agent/model.pb (camera, stereo or lidar models); " +
      "DeepRacer-on-AWS and DRfC take the rl_coach tree (clipped PPO)." }),
    ...buttons.flatMap(b => [b, " "]), status, files));
  refresh();
}

async function viewExchange() {
  const x = await api("GET", "/api/exchange");
  const file = el("input", { type: "file", id: "import-file", accept: x.import_suffixes.join(",") });
  const name = el("input", { id: "import-name", placeholder: "new model name" });
  const status = el("p", { id: "import-status", class: "muted" });
  const go = el("button", { id: "import-start", text: "Import", onclick: async () => {
    if (!file.files.length) { toast("choose an archive first", true); return; }
    const form = new FormData(); form.append("file", file.files[0]); form.append("name", name.value.trim());
    go.disabled = true;
    const r = await guarded(() => api("POST", "/api/imports", form, true));
    if (!r) { go.disabled = false; return; }
    status.textContent = `importing ${r.name}…`;
    pollTask(r.task.key, (done) => {
      go.disabled = false;
      if (done.status !== "done") { status.textContent = done.message; return; }
      status.replaceChildren(el("a", { href: "#/model/" + encodeURIComponent(done.result.model), text: done.result.model }),
        " imported.");
    });
  } });
  main.append(el("h1", { text: "Exchange" }), el("div", { class: "card", id: "exchange" },
    el("h2", { text: "Import a model" }),
    el("p", { text: `A console, DeepRacer-on-AWS, DRfC or car archive (${x.import_suffixes.join(", ")}, at most ` +
      `${(x.upload_limit / 1e6).toFixed(0)} MB) becomes a new model folder. Exports are on each model's exchange tab.` }),
    file, " ", name, " ", go, status));
}

// ---- races --------------------------------------------------------------------------------------------------
async function viewRaces() {
  const models = await guarded(() => api("GET", "/api/models"));
  if (!models) return;
  const boxes = models.models.map(m => el("label", {}, el("input", { type: "checkbox", value: m.name, "data-race": "1" }), " " + m.name + "  "));
  const rules = rulesForm("race");
  const boards = el("div");
  // a race runs until its last model's last lap; Cancel stops it at the end of the lap on the track
  const cancel = el("button", { id: "race-cancel", text: "Cancel race", disabled: true, onclick: async () => {
    if (await guarded(() => api("POST", "/api/tasks/race/cancel"))) { cancel.disabled = true; toast("cancelling…"); }
  } });
  const go = el("button", { id: "race-start", text: "Start race", onclick: async () => {
    const chosen = [...main.querySelectorAll("input[data-race]:checked")].map(i => i.value);
    const t = await guarded(() => api("POST", "/api/races", { models: chosen, ...rules.values() }));
    if (!t) return;
    go.disabled = true; cancel.disabled = false; toast("racing…");
    pollTask(t.key, done => {
      go.disabled = false; cancel.disabled = true;
      if (done.status === "cancelled") toast(done.message);
      refresh();
    });
  } });
  main.append(el("h1", { text: "Races" }), el("div", { class: "card" }, el("p", {}, ...boxes), rules.grid, el("p", {}, go, " ", cancel)), boards);
  async function refresh() {
    const d = await guarded(() => api("GET", "/api/races"));
    if (!d) return;
    boards.replaceChildren(...d.races.map(r => el("div", { class: "card" },
      el("h3", { text: `${r.name} · ${r.track} · ${r.rules.trials} ${r.rules.continuous ? "continuous lap" : "trial"}${r.rules.trials === 1 ? "" : "s"}` }),
      el("table", {}, el("tr", {}, ...["rank", "model", "best lap", `avg ${r.ranking_laps}`, "laps", "off-track", "result"].map(h => el("th", { text: h }))),
        ...r.leaderboard.map(row => el("tr", {}, el("td", { text: String(row.rank) }), el("td", { text: row.model }),
          el("td", { text: fmt(row.best_lap, 3) }), el("td", { text: fmt(row.ranking_average, 3) }),
          el("td", { text: `${row.laps_completed}/${row.laps}` }), el("td", { text: String(row.off_track) }), el("td", { text: row.result })))))));
  }
  refresh();
}

// ---- analysis: racing line and uploaded logs ------------------------------------------------------------------------
async function viewAnalysis() {
  const tracks = await guarded(() => api("GET", "/api/tracks"));
  const methods = await guarded(() => api("GET", "/api/lines/methods"));
  if (!tracks || !methods) return;
  const sel = el("select", { id: "line-track" }, ...tracks.tracks.map(t => el("option", { value: t, text: t })));
  const method = el("select", { id: "line-method" }, ...methods.methods.map(m => el("option", { text: m })));
  const lineOut = el("div");
  const go = el("button", { id: "line-make", text: "Solve racing line", onclick: async () => {
    const t = await guarded(() => api("POST", "/api/lines", { track: sel.value, method: method.value }));
    if (!t) return;
    go.disabled = true;
    pollTask(t.key, (done) => {
      go.disabled = false;
      if (done.status !== "done") return;
      const s = done.result.summary, lim = done.result.limit;
      lineOut.replaceChildren(el("p", { id: "line-summary", text: `this line: lap ${fmt(s.lap_time_s, 3)} s (flying ${fmt(s.flying_lap_time_s, 3)} s), ${s.length_m} m, the whole car inside the borders` }),
        el("p", { id: "line-limit", text: lim.error ? `the limit: not solved (${lim.error})` : `the limit: lap ${fmt(lim.lap_time_s, 3)} s (flying ${fmt(lim.flying_lap_time_s, 3)} s), the theoretical best lap under the simulator's off-track rule (a car is off only when no wheel centre is on the road)` }),
        el("img", { src: `/api/lines/${encodeURIComponent(sel.value)}/${method.value}.png?t=${Date.now()}`, style: "max-width:100%" }),
        el("h3", { text: "racing_line for a reward function" }), el("pre", { text: done.result.python }));
    });
  } });
  const file = el("input", { type: "file", id: "upload-file", accept: ".tar.gz,.tgz,.tar" });
  const uploads = el("div");
  const up = el("button", { id: "upload-start", text: "Upload and analyse", onclick: async () => {
    if (!file.files.length) return toast("choose a .tar.gz of DRfC or console logs", true);
    const form = new FormData(); form.append("file", file.files[0]);
    const r = await guarded(() => api("POST", "/api/uploads", form, true));
    if (!r) return;
    toast(`${r.name}: ${r.files} files; writing the report…`);
    pollTask(r.task.key, refreshUploads);
  } });
  const frame = el("div");
  async function refreshUploads() {
    const d = await guarded(() => api("GET", "/api/uploads")); if (!d) return;
    uploads.replaceChildren(...d.uploads.map(u => el("p", {}, el("span", { text: `${u.name} (${(u.bytes / 1e6).toFixed(1)} MB) ` }),
      u.report ? el("button", { class: "secondary", text: "show report", onclick: () => frame.replaceChildren(reportFrame(`/api/uploads/${encodeURIComponent(u.name)}/report`)) })
               : el("span", { class: "muted", text: "no report" }))));
  }
  main.append(el("h1", { text: "Analysis" }),
    el("div", { class: "card" }, el("h2", { text: "Racing line" }), sel, " ", method, " ", go, lineOut),
    el("div", { class: "card" }, el("h2", { text: "Log archives (DRfC, console exports)" }), file, " ", up, uploads), frame);
  refreshUploads();
}

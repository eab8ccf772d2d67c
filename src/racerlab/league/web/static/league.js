// racerlab league: the little the pages need beyond HTML. Every text from the server is set with textContent
// (aliases and model names are strangers' text); nothing here builds HTML from strings.
"use strict";

const WORDS = {queued: "queued", evaluating: "under evaluation", ranked: "ranked", not_ranked: "not ranked",
  no_lap: "no lap", refused: "refused", failed: "failed"};

function el(tag, attrs, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") node.className = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(c == null ? "" : String(c)));
  return node;
}

function laptime(seconds) {
  if (seconds == null) return "—";
  const ms = Math.round(seconds * 1000);
  return `${Math.floor(ms / 60000)}:${((ms % 60000) / 1000).toFixed(3).padStart(6, "0")}`;
}

function eta(s) {
  if (s == null) return "waiting for a worker";
  return s < 90 ? `about ${Math.round(s)} s` : `about ${Math.round(s / 60)} min`;
}

function localTimes(root) {
  for (const t of (root || document).querySelectorAll("time[datetime]")) {
    const d = new Date(t.getAttribute("datetime"));
    if (isNaN(d)) continue;
    t.title = t.getAttribute("datetime");
    t.textContent = d.toLocaleString(undefined, {day: "numeric", month: "short", hour: "2-digit", minute: "2-digit",
      second: "2-digit"});
  }
}

function badge(status, text) {
  return el("span", {class: `badge ${status}`}, text || WORDS[status] || status);
}

function why(s) {
  return s.status === "queued" ? `#${s.position} in the queue, ${eta(s.eta_s)}` : (s.reason || "");
}

// ---- the race page: live leaderboard and the caller's submissions ------------------------------------------------
function boardRow(row, me, previous, video) {
  const ranked = row.rank != null;
  const tr = el("tr", {class: `${row.alias === me ? "me" : ""} ${ranked ? "" : "unranked"}`, "data-alias": row.alias},
    el("td", {class: "num"}, ranked ? row.rank : "—"),
    el("td", {}, row.alias),
    el("td", {class: "num"}, ranked ? laptime(row.time_s) : badge(row.status)),
    el("td", {class: "num"}, ranked ? (row.gap_s === 0 ? "leader" : `+${row.gap_s.toFixed(3)}`) : ""),
    el("td", {class: "num"}, row.off_track == null ? "—" : row.off_track),
    el("td", {class: "num"}, row.laps_completed == null ? "—" : row.laps_completed),
    el("td", {class: "num"}, row.submissions),
    el("td", {}, row.video && video ? el("a", {href: `/api/submissions/${row.submission_id}/files/video`, target: "_blank",
      rel: "noopener"}, "watch") : ""));
  const key = `${row.rank}|${row.time_s}|${row.status}|${row.submissions}`;
  if (previous && previous.get(row.alias) !== key) tr.classList.add("flash-row");
  return [tr, key];
}

function renderBoard(standings, me, state, video) {
  const body = document.querySelector("#leaderboard tbody");
  const seen = new Map();
  const rows = standings.rows.map((r) => {
    const [tr, key] = boardRow(r, me, state.keys, video);
    seen.set(r.alias, key);
    return tr;
  });
  if (!rows.length) {
    rows.push(el("tr", {class: "empty"}, el("td", {colspan: "8", class: "muted"},
      "No results yet: the first ranked submission takes the top spot.")));
  }
  body.replaceChildren(...rows);
  state.keys = seen;
}

function renderMine(mine) {
  const body = document.querySelector("#mine tbody");
  if (!body) return;
  const rows = mine.map((s) => el("tr", {"data-id": s.id, "data-status": s.status},
    el("td", {class: "num"}, el("a", {href: `/submissions/${s.id}`}, s.number)),
    el("td", {}, s.model_name, el("div", {class: "muted small"}, s.checkpoint)),
    el("td", {}, el("time", {datetime: s.created_at}, s.created_at)),
    el("td", {}, badge(s.status, s.status_text), el("div", {class: "small why"}, why(s))),
    el("td", {class: "num"}, s.score_ms == null ? "—" : laptime(s.score_ms / 1000)),
    el("td", {class: "num"}, s.laps_completed == null ? "—" : s.laps_completed)));
  if (!rows.length) rows.push(el("tr", {class: "empty"}, el("td", {colspan: "6", class: "muted"}, "None yet.")));
  body.replaceChildren(...rows);
  localTimes(body);
}

function liveRace(root) {
  const name = root.dataset.race, me = root.dataset.me;
  const dot = document.getElementById("live-dot"), word = document.getElementById("live-state");
  const state = {keys: null};
  const source = new EventSource(`/api/races/${encodeURIComponent(name)}/events`);
  source.addEventListener("board", (ev) => {
    const data = JSON.parse(ev.data);
    renderBoard(data.standings, me, state, root.dataset.video === "yes");
    renderMine(data.mine);
    root.dataset.version = data.race.version;
    document.getElementById("used").textContent = data.race.submissions_used;
    const badgeEl = document.getElementById("race-state");
    badgeEl.textContent = data.race.state;
    badgeEl.className = `badge ${data.race.state}`;
    dot.classList.add("on");
    word.textContent = "live";
    document.body.dataset.boardVersion = data.race.version;  // tests wait on it
  });
  source.addEventListener("error", (ev) => {
    dot.classList.remove("on");
    word.textContent = ev.data ? JSON.parse(ev.data).error : "reconnecting…";
    if (ev.data) source.close();
  });
}

// ---- a submission's page: follow its status until it is final ----------------------------------------------------
function followSubmission(root) {
  if (root.dataset.final === "yes") return;
  const id = root.dataset.id;
  const tick = async () => {
    try {
      const res = await fetch(`/api/submissions/${id}`, {headers: {Accept: "application/json"}});
      if (!res.ok) return;
      const s = await res.json();
      if (s.status !== root.dataset.status) {
        window.location.reload();
        return;
      }
      document.getElementById("why").textContent = s.status === "evaluating" ? "on the track now" : why(s);
    } finally {
      setTimeout(tick, 1500);
    }
  };
  setTimeout(tick, 1500);
}

// ---- forms --------------------------------------------------------------------------------------------------
function forms() {
  for (const tz of document.querySelectorAll("input.tz")) tz.value = String(new Date().getTimezoneOffset());
  const upload = document.getElementById("upload-form");
  if (upload) {
    upload.addEventListener("submit", () => {
      document.getElementById("submit-model").disabled = true;
      document.getElementById("upload-note").hidden = false;
    });
  }
  for (const b of document.querySelectorAll(".copy-button")) {
    b.addEventListener("click", async () => {
      const text = document.getElementById(b.dataset.copy).textContent;
      try { await navigator.clipboard.writeText(text); b.textContent = "Copied"; } catch (e) { b.textContent = "Select and copy"; }
    });
  }
}

document.addEventListener("DOMContentLoaded", () => {
  localTimes();
  forms();
  const race = document.getElementById("race");
  if (race && document.getElementById("leaderboard")) liveRace(race);
  const sub = document.getElementById("submission");
  if (sub) followSubmission(sub);
});

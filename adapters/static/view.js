// arcf live view: plain JavaScript, no library, nothing fetched from elsewhere.
"use strict";

const HISTORY = 300; // results plotted per session
const stream = new URLSearchParams(location.search).get("stream");
const sessions = new Map(); // session id -> {colour, points: [{seq, confidence, aberrance}], last}
let presets = new Map();
let lastSeq = null;
// tracking control (arcf-view --allow-control): what the page may do, and the session a drawn
// box re-initialises (none: it starts a new one)
const control = { on: false, selected: null, last: null, token: takeToken() };

// The control token arrives in the address's fragment (#token=..., printed by arcf-view): kept
// for this tab, then removed from the address bar, so that it is neither bookmarked nor shown.
function takeToken() {
  const given = new URLSearchParams(location.hash.slice(1)).get("token");
  if (given) {
    sessionStorage.setItem("arcf-view-token", given);
    history.replaceState(null, "", location.pathname + location.search);
  }
  return sessionStorage.getItem("arcf-view-token");
}

function el(tag, text, attrs = {}) {
  const e = document.createElement(tag);
  if (text !== undefined) e.textContent = text;
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
}

async function refreshStreams() {
  const list = document.getElementById("streams");
  const state = document.getElementById("service-state");
  try {
    const doc = await (await fetch("/api/streams", { cache: "no-store" })).json();
    state.textContent = doc.error || "";
    state.className = doc.error ? "error" : "";
    list.replaceChildren();
    presets = new Map();
    if (!doc.streams.length) list.append(el("li", "no stream yet", { class: "muted" }));
    for (const s of doc.streams) {
      const li = el("li");
      const a = el("a", s.stream_id, { href: "?stream=" + encodeURIComponent(s.stream_id) });
      if (s.stream_id === stream) a.className = "current";
      const n = s.sessions.length;
      li.append(a, el("span", n ? " · " + n + " session(s)" : " · no session", { class: "muted" }));
      list.append(li);
      for (const x of s.sessions) presets.set(x.session_id, x.preset);
    }
  } catch (err) {
    state.textContent = "the live view's server does not answer";
    state.className = "error";
  }
}

function fmt(v, digits) { return v === null || v === undefined ? "–" : v.toFixed(digits); }

// what a row says: the track state, or why the session has no current box (the reason in
// full as the row's title)
function stateText(r) {
  if (r.status === "stale") return "stale: no frames";
  if (r.status === "error") return "error: " + (r.code || "?");
  if (r.status === "stopped") return "interrupted: the service stopped";
  return r.state || r.status;
}

function renderTable() {
  const body = document.querySelector("#sessions tbody");
  body.replaceChildren();
  if (control.selected && !sessions.has(control.selected)) select(null); // it ended
  for (const [id, s] of sessions) {
    const r = s.last;
    const name = el("td");
    name.append(el("span", "", { class: "swatch", style: "background:" + s.colour }), id.slice(0, 8));
    // stale: the stream sent no frame for the service's stale_after_s; the box is not current
    const stale = r.status === "stale";
    const classes = [stale ? "stale" : "", id === control.selected ? "selected" : ""].join(" ");
    const row = el("tr", undefined, { class: classes.trim(), "data-session": id,
      title: r.message || "" });
    const actions = el("td");
    if (control.on && control.token) {
      const pick = el("button", id === control.selected ? "selected" : "re-draw", { type: "button", class: "select" });
      pick.onclick = () => select(id === control.selected ? null : id);
      const stop = el("button", "stop", { type: "button", class: "stop" });
      stop.onclick = () => send("/api/sessions/" + encodeURIComponent(id) + "/stop", {});
      actions.append(pick, " ", stop);
    }
    row.append(name, el("td", presets.get(id) || "–"),
      el("td", stateText(r)),
      el("td", fmt(r.confidence, 2)), el("td", fmt(r.aberrance, 4)), el("td", String(r.frame_seq)),
      actions);
    body.append(row);
  }
}

// ---- tracking control: drag a box on the picture to start (or re-initialise) a session

function select(id) {
  control.selected = id;
  document.getElementById("new-session").hidden = id === null;
  hint();
}

function hint() {
  const text = !control.on ? "view only: tracking control is off (arcf-view --allow-control)"
    : !control.token ? "view only: control needs the view's token (open the address arcf-view printed)"
    : control.selected ? "drag a box to re-initialise " + control.selected.slice(0, 8)
    : "drag a box around a target to track it";
  document.getElementById("control-hint").textContent = text;
  document.getElementById("draw").classList.toggle("on", control.on && !!control.token);
}

async function send(path, body) {
  const state = document.getElementById("control-state");
  let reply;
  try {
    const headers = { "Content-Type": "application/json" };
    if (control.token) headers.Authorization = "Bearer " + control.token;
    const r = await fetch(path, { method: "POST", headers, body: JSON.stringify(body),
      cache: "no-store" });
    reply = { status: r.status, ...(await r.json()) };
  } catch (err) {
    reply = { status: 0, message: "the live view's server does not answer" };
  }
  control.last = reply;
  const ok = reply.status >= 200 && reply.status < 300;
  const done = { sessions: "started", reinit: "re-initialised", stop: "stopped" }[path.split("/").pop()];
  state.textContent = ok ? "session " + reply.session_id.slice(0, 8) + " " + done
    : reply.message || ("refused (" + reply.status + ")");
  state.className = ok ? "" : "error";
  refreshStreams();
  return reply;
}

function setUpDrawing() {
  const img = document.getElementById("video");
  const canvas = document.getElementById("draw");
  const ctx = canvas.getContext("2d");
  let from = null;
  const at = (e) => { const b = canvas.getBoundingClientRect(); return [e.clientX - b.left, e.clientY - b.top]; };
  const rect = (a, b) => [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.abs(a[0] - b[0]), Math.abs(a[1] - b[1])];
  const clear = () => { canvas.width = canvas.clientWidth; canvas.height = canvas.clientHeight; };
  canvas.addEventListener("pointerdown", (e) => {
    if (!control.on || !control.token || !img.naturalWidth || e.button !== 0) return;
    from = at(e);
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointermove", (e) => {
    if (!from) return;
    clear();
    const [x, y, w, h] = rect(from, at(e));
    ctx.strokeStyle = "#fff"; ctx.setLineDash([6, 4]); ctx.lineWidth = 2;
    ctx.strokeRect(x, y, w, h);
  });
  canvas.addEventListener("pointerup", (e) => {
    if (!from) return;
    const [x, y, w, h] = rect(from, at(e));
    from = null;
    clear();
    if (w < 4 || h < 4) return; // a click, not a box
    // the picture may be scaled twice: by the server (max_width) and by the page's layout
    const k = Number(img.dataset.frameWidth || img.naturalWidth) / canvas.clientWidth;
    const box = [x * k + 1, y * k + 1, w * k, h * k]; // 1-based, as results
    const seq = img.dataset.frameSeq; // the frame the box was drawn on, when the view knows it
    const body = { box, ...(seq ? { frame_seq: Number(seq) } : {}) };
    if (control.selected) {
      send("/api/sessions/" + encodeURIComponent(control.selected) + "/reinit", body);
    } else {
      body.preset = document.getElementById("preset").value;
      send("/api/streams/" + encodeURIComponent(stream) + "/sessions", body);
    }
  });
  document.getElementById("new-session").onclick = () => select(null);
  document.addEventListener("keydown", (e) => { if (e.key === "Escape") select(null); });
}

async function setUpControl() {
  try {
    const config = await (await fetch("/api/config", { cache: "no-store" })).json();
    control.on = config.control;
    const choice = document.getElementById("preset");
    for (const name of config.presets) choice.append(el("option", name, { value: name }));
    choice.value = config.preset;
    choice.disabled = !control.on || !control.token;
  } catch (err) {
    control.on = false;
  }
  hint();
  control.ready = true;
}

function renderPlot() {
  const canvas = document.getElementById("plot");
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, pad = 6;
  ctx.clearRect(0, 0, w, h);
  ctx.strokeStyle = "#333";
  ctx.beginPath(); ctx.moveTo(0, h / 2); ctx.lineTo(w, h / 2); ctx.stroke();
  if (lastSeq === null) return;
  const x = (seq) => w - pad - (lastSeq - seq) * (w - 2 * pad) / HISTORY;
  for (const s of sessions.values()) {
    const top = Math.max(1e-9, ...s.points.map((p) => p.aberrance || 0));
    for (const [key, scale, dash] of [["confidence", 1, []], ["aberrance", top, [5, 4]]]) {
      ctx.strokeStyle = s.colour; ctx.setLineDash(dash); ctx.lineWidth = 1.5;
      ctx.beginPath();
      let drawing = false;
      for (const p of s.points) {
        const v = p[key];
        if (v === null || v === undefined) { drawing = false; continue; }
        const y = h - pad - (v / scale) * (h - 2 * pad);
        if (drawing) ctx.lineTo(x(p.seq), y); else ctx.moveTo(x(p.seq), y);
        drawing = true;
      }
      ctx.stroke();
    }
  }
  ctx.setLineDash([]);
}

async function pictures(url) {
  // the next rendered picture once the last is shown: a slow viewer skips, never lags
  const img = document.getElementById("video");
  let after = -1;
  for (;;) {
    try {
      const reply = await fetch(url + "?after=" + after, { cache: "no-store" });
      if (reply.status === 200) {
        after = Number(reply.headers.get("X-Rendered"));
        const shown = URL.createObjectURL(await reply.blob());
        await new Promise((done) => { img.onload = img.onerror = done; img.src = shown; });
        if (img.dataset.url) URL.revokeObjectURL(img.dataset.url);
        img.dataset.url = shown;
        img.dataset.frameSeq = reply.headers.get("X-Frame-Seq") || "";
        img.dataset.frameWidth = reply.headers.get("X-Frame-Width") || "";
      } else if (reply.status !== 204) {
        await new Promise((done) => setTimeout(done, 1000));
      }
    } catch (err) {
      await new Promise((done) => setTimeout(done, 1000));
    }
  }
}

function watch() {
  document.getElementById("watch").hidden = false;
  document.getElementById("stream-name").textContent = stream;
  const base = "/api/streams/" + encodeURIComponent(stream);
  pictures(base + "/frame.jpg");
  setUpDrawing();
  setUpControl();
  const events = new EventSource(base + "/results");
  events.onmessage = (msg) => {
    const r = JSON.parse(msg.data);
    let s = sessions.get(r.session_id);
    if (!s) { s = { colour: r.colour, points: [] }; sessions.set(r.session_id, s); }
    s.last = r;
    if (r.status !== "stale") { // a notice about no frame: nothing to plot
      s.points.push({ seq: r.frame_seq, confidence: r.confidence, aberrance: r.aberrance });
      if (s.points.length > HISTORY) s.points.shift();
    }
    // ended; but an interrupted session (its instance stopped) resumes under its id
    if (r.status === "stopped" && r.code !== "interrupted") sessions.delete(r.session_id);
    lastSeq = lastSeq === null ? r.frame_seq : Math.max(lastSeq, r.frame_seq);
    document.getElementById("frame-seq").textContent = String(lastSeq);
  };
  setInterval(() => { renderTable(); renderPlot(); }, 250);
}

window.arcfView = { sessions, control, points: () => [...sessions.values()].reduce((n, s) => n + s.points.length, 0) };
document.getElementById("by-name").addEventListener("submit", (e) => {
  e.preventDefault();
  location.search = "?stream=" + encodeURIComponent(document.getElementById("stream-input").value);
});
refreshStreams();
setInterval(refreshStreams, 2000);
if (stream) watch();

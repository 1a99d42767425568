// arcf live view: plain JavaScript, no library, nothing fetched from elsewhere.
"use strict";

const HISTORY = 300; // results plotted per session
const stream = new URLSearchParams(location.search).get("stream");
const sessions = new Map(); // session id -> {colour, points: [{seq, confidence, aberrance}], last}
let presets = new Map();
let lastSeq = null;

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
    if (!doc.streams.length) list.append(el("li", "no stream has a session", { class: "muted" }));
    for (const s of doc.streams) {
      const li = el("li");
      const a = el("a", s.stream_id, { href: "?stream=" + encodeURIComponent(s.stream_id) });
      if (s.stream_id === stream) a.className = "current";
      li.append(a, el("span", " · " + s.sessions.length + " session(s)", { class: "muted" }));
      list.append(li);
      for (const x of s.sessions) presets.set(x.session_id, x.preset);
    }
  } catch (err) {
    state.textContent = "the live view's server does not answer";
    state.className = "error";
  }
}

function fmt(v, digits) { return v === null || v === undefined ? "–" : v.toFixed(digits); }

function renderTable() {
  const body = document.querySelector("#sessions tbody");
  body.replaceChildren();
  for (const [id, s] of sessions) {
    const r = s.last;
    const name = el("td");
    name.append(el("span", "", { class: "swatch", style: "background:" + s.colour }), id.slice(0, 8));
    // stale: the stream sent no frame for the service's stale_after_s; the box is not current
    const stale = r.status === "stale";
    const row = el("tr", undefined, stale ? { class: "stale", title: r.message || "" } : {});
    row.append(name, el("td", presets.get(id) || "–"),
      el("td", stale ? "stale: no frames" : (r.state || r.status)),
      el("td", fmt(r.confidence, 2)), el("td", fmt(r.aberrance, 4)), el("td", String(r.frame_seq)));
    body.append(row);
  }
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
        img.dataset.frameSeq = reply.headers.get("X-Frame-Seq");
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
    if (r.status === "stopped") sessions.delete(r.session_id);
    lastSeq = lastSeq === null ? r.frame_seq : Math.max(lastSeq, r.frame_seq);
    document.getElementById("frame-seq").textContent = String(lastSeq);
  };
  setInterval(() => { renderTable(); renderPlot(); }, 250);
}

window.arcfView = { sessions, points: () => [...sessions.values()].reduce((n, s) => n + s.points.length, 0) };
refreshStreams();
setInterval(refreshStreams, 2000);
if (stream) watch();

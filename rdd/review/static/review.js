// rdd review: the list of episodes (lowest confidence first) and an episode's editor.
// Plain JavaScript, no build step; the server (rdd/review/app.py) holds the state and writes --out.
"use strict";

const $ = (id) => document.getElementById(id);
const state = { page: 0, size: 50, total: 0, ep: null, rec: null, undo: [], cursor: 0, sel: 0, handle: null, pending: 0 };

function status(text) { $("status").textContent = text; }

async function api(method, url, body) {
  const opts = { method, headers: {} };
  if (body !== undefined) { opts.headers["Content-Type"] = "application/json"; opts.body = JSON.stringify(body); }
  const res = await fetch(url, opts);
  const data = await res.json();
  if (!res.ok) { throw new Error(data.error || res.statusText); }
  return data;
}

// Confidence 0 -> red, 1 -> green; unknown (a person's segment) -> blue-grey.
function colour(c) {
  if (c === null || c === undefined) { return "hsl(210, 25%, 75%)"; }
  return `hsl(${Math.round(120 * c)}, 70%, 70%)`;
}

// ---------------------------------------------------------------- the list
async function loadList() {
  const q = encodeURIComponent($("filter").value);
  const data = await api("GET", `/api/episodes?page=${state.page}&size=${state.size}&q=${q}&only=${$("only").value}`);
  state.total = data.total;
  $("summary").textContent = `${data.episodes} episodes, ${data.flagged} below ${data.review_below} (flagged)`;
  const pages = Math.max(1, Math.ceil(data.total / state.size));
  $("pageinfo").textContent = `page ${data.page + 1} of ${pages} (${data.total} shown)`;
  $("prev").disabled = state.page === 0;
  $("next").disabled = state.page + 1 >= pages;
  const body = $("list").querySelector("tbody");
  body.replaceChildren();
  for (const row of data.items) {
    const tr = document.createElement("tr");
    tr.dataset.episode = row.episode;
    const flags = [row.flagged ? "<span class=flag>check</span>" : "", row.edited ? "edited" : "",
                   row.reviewed ? "<span class=ok>reviewed</span>" : ""].filter(Boolean).join(" ");
    tr.innerHTML = `<td></td><td style="background:${colour(row.lowest)}">${row.lowest.toFixed(3)}</td>` +
      `<td>${row.segments}</td><td>${row.num_frames}</td>` +
      `<td>${row.novelty === null || row.novelty === undefined ? "" : row.novelty.toFixed(3)}</td><td>${flags}</td>`;
    tr.firstChild.textContent = row.episode;  // a name is text, never markup
    tr.addEventListener("click", () => openEpisode(row.episode));
    body.appendChild(tr);
  }
  status("");
}

// ---------------------------------------------------------------- an episode
async function openEpisode(name) {
  status(`loading ${name} ...`);
  const data = await api("GET", `/api/episode/${encodeURIComponent(name)}`);
  state.ep = data;
  state.rec = data.record;
  state.undo = [];
  state.cursor = 0;
  state.sel = 0;
  state.handle = null;
  $("list-view").hidden = true;
  $("episode-view").hidden = false;
  $("ep-name").textContent = name;
  $("reviewed").checked = !!state.rec.reviewed;
  $("scrub").max = state.rec.num_frames - 1;
  $("scrub").value = 0;
  const frames = $("frames");
  frames.replaceChildren();
  for (const view of data.views) {
    const fig = document.createElement("figure");
    const img = document.createElement("img");
    img.dataset.view = view;
    img.alt = view;
    const cap = document.createElement("figcaption");
    cap.textContent = view;
    fig.append(img, cap);
    frames.appendChild(fig);
  }
  drawSignals();
  render();
  status("");
}

function showFrame() {
  const name = encodeURIComponent(state.rec.episode);
  for (const img of $("frames").querySelectorAll("img")) {
    img.src = `/api/frame/${name}/${encodeURIComponent(img.dataset.view)}/${state.cursor}`;
  }
  $("scrub").value = state.cursor;
  $("cursor-info").textContent = `frame ${state.cursor} of ${state.rec.num_frames}`;
}

function render() {
  const rec = state.rec;
  const n = rec.num_frames;
  const tl = $("timeline");
  tl.replaceChildren();
  rec.segments.forEach(([s, e], k) => {
    const div = document.createElement("div");
    div.className = "seg" + (k === state.sel ? " selected" : "");
    div.dataset.k = k;
    div.style.left = `${100 * s / n}%`;
    div.style.width = `${100 * (e - s) / n}%`;
    div.style.background = colour(rec.confidence ? rec.confidence[k] : null);
    div.textContent = rec.instructions[k] || `(segment ${k + 1})`;
    div.title = `[${s}, ${e})`;
    div.addEventListener("click", (ev) => { state.sel = k; state.cursor = frameAt(ev); render(); });
    tl.appendChild(div);
  });
  rec.segments.slice(1).forEach(([s], b) => {
    const h = document.createElement("div");
    h.className = "handle" + (state.handle === b ? " selected" : "");
    h.dataset.b = b;
    h.style.left = `${100 * s / n}%`;
    h.title = `boundary at frame ${s}`;
    h.addEventListener("mousedown", (ev) => { ev.preventDefault(); ev.stopPropagation(); state.handle = b; drag(ev); render(); });
    tl.appendChild(h);
  });
  const cur = document.createElement("div");
  cur.id = "cursor";
  cur.style.left = `${100 * state.cursor / n}%`;
  tl.appendChild(cur);
  panel();
  showFrame();
}

function frameAt(ev) {
  const box = $("timeline").getBoundingClientRect();
  const x = Math.min(Math.max(ev.clientX - box.left, 0), box.width);
  return Math.min(state.rec.num_frames - 1, Math.floor(state.rec.num_frames * x / box.width));
}

function panel() {
  const rec = state.rec;
  const k = Math.min(state.sel, rec.segments.length - 1);
  state.sel = k;
  const [s, e] = rec.segments[k];
  $("seg-index").textContent = `${k + 1} of ${rec.segments.length}`;
  $("seg-range").textContent = `[${s}, ${e})`;
  const c = rec.confidence ? rec.confidence[k] : null;
  $("seg-conf").textContent = c === null || c === undefined ? "none (a person's)" : c.toFixed(2);
  $("seg-source").textContent = rec.sources ? rec.sources[k] : "rdd";
  $("label").value = rec.instructions[k] || "";
  const match = $("match");
  match.replaceChildren();
  const name = encodeURIComponent(rec.episode);
  const add = (src, text) => {
    const fig = document.createElement("figure");
    const img = document.createElement("img");
    img.src = src;
    img.alt = text;
    const cap = document.createElement("figcaption");
    cap.textContent = text;
    fig.append(img, cap);
    match.appendChild(fig);
  };
  const view = encodeURIComponent(state.ep.views[0]);
  add(`/api/frame/${name}/${view}/${s}`, `this segment: first frame ${s}`);
  add(`/api/frame/${name}/${view}/${e - 1}`, `this segment: last frame ${e - 1}`);
  const nb = rec.neighbours ? rec.neighbours[k] : null;
  if (nb && state.ep.has_database) {
    const label = nb.label ? ` "${nb.label}"` : "";
    add(`/api/neighbour/${nb.entry}/begin/${view}`, `match: ${nb.episode} [${nb.segment[0]}, ${nb.segment[1]})${label} first`);
    add(`/api/neighbour/${nb.entry}/end/${view}`, `match: last frame, distance ${nb.distance.toFixed(3)}`);
  } else if (nb) {
    const p = document.createElement("p");
    p.textContent = `matched ${nb.episode} [${nb.segment[0]}, ${nb.segment[1]}) (pass --db to see its frames)`;
    match.appendChild(p);
  }
}

function drawSignals() {
  const svg = $("signals");
  svg.replaceChildren();
  $("legend").replaceChildren();
  $("signals").hidden = Object.keys(state.ep.signals).length === 0;
  const n = state.rec.num_frames;
  svg.setAttribute("viewBox", `0 0 ${n} 100`);
  const hues = [0, 210, 120, 280, 30, 180];
  Object.entries(state.ep.signals).forEach(([name, values], i) => {
    const lo = Math.min(...values), hi = Math.max(...values), span = hi - lo || 1;
    const pts = values.map((v, t) => `${t},${(95 - 90 * (v - lo) / span).toFixed(1)}`).join(" ");
    const line = document.createElementNS("http://www.w3.org/2000/svg", "polyline");
    line.setAttribute("points", pts);
    line.setAttribute("fill", "none");
    line.setAttribute("stroke", `hsl(${hues[i % hues.length]}, 70%, 40%)`);
    line.setAttribute("vector-effect", "non-scaling-stroke");
    const title = document.createElementNS("http://www.w3.org/2000/svg", "title");
    title.textContent = name;
    line.appendChild(title);
    svg.appendChild(line);
    const key = document.createElement("span");
    key.textContent = name;
    key.style.color = `hsl(${hues[i % hues.length]}, 70%, 40%)`;
    $("legend").appendChild(key);
  });
}

// ---------------------------------------------------------------- editing
function snapshot() {
  state.undo.push(JSON.stringify({ segments: state.rec.segments, instructions: state.rec.instructions,
                                   reviewed: $("reviewed").checked }));
}

// Edits apply at once on the page and go to the server one after another; the server's version
// (with who changed what) replaces the page's only when no later edit is still on its way.
let chain = Promise.resolve();
function commit() {
  const body = { segments: state.rec.segments, instructions: state.rec.instructions, reviewed: $("reviewed").checked };
  const url = `/api/episode/${encodeURIComponent(state.rec.episode)}`;
  state.pending += 1;
  render();
  chain = chain.then(async () => {
    try {
      const data = await api("PUT", url, JSON.parse(JSON.stringify(body)));
      state.pending -= 1;
      if (state.pending === 0) {
        state.rec = data.record;
        render();
        status("changed (not saved yet)");
      }
    } catch (err) {
      state.pending -= 1;
      status(`error: ${err.message}`);
    }
  });
  return chain;
}

function moveBoundary(b, to) {
  const segs = state.rec.segments;
  const lo = segs[b][0] + 1, hi = segs[b + 1][1] - 1;
  const at = Math.min(Math.max(to, lo), hi);
  if (at === segs[b + 1][0]) { return false; }
  segs[b][1] = at;
  segs[b + 1][0] = at;
  return true;
}

function drag(ev) {
  const b = state.handle;
  let moved = false;
  snapshot();
  const move = (e) => { if (moveBoundary(b, frameAt(e))) { moved = true; state.cursor = state.rec.segments[b + 1][0]; render(); } };
  const up = () => {
    document.removeEventListener("mousemove", move);
    document.removeEventListener("mouseup", up);
    if (moved) { commit(); } else { state.undo.pop(); }
  };
  document.addEventListener("mousemove", move);
  document.addEventListener("mouseup", up);
}

function split() {
  const segs = state.rec.segments;
  const k = segs.findIndex(([s, e]) => s < state.cursor && state.cursor < e);
  if (k < 0) { status("split: put the cursor inside a segment, not on its first frame"); return; }
  snapshot();
  const [s, e] = segs[k];
  segs.splice(k, 1, [s, state.cursor], [state.cursor, e]);
  state.rec.instructions.splice(k + 1, 0, state.rec.instructions[k]);
  state.sel = k + 1;
  commit();
}

function merge() {
  const k = state.sel, segs = state.rec.segments;
  if (k + 1 >= segs.length) { status("merge: the selected segment is the last"); return; }
  snapshot();
  segs.splice(k, 2, [segs[k][0], segs[k + 1][1]]);
  state.rec.instructions.splice(k + 1, 1);
  commit();
}

function undo() {
  const last = state.undo.pop();
  if (!last) { status("nothing to undo"); return; }
  const old = JSON.parse(last);
  state.rec.segments = old.segments;
  state.rec.instructions = old.instructions;
  $("reviewed").checked = old.reviewed;
  commit();
}

async function save() {
  await chain;
  try {
    const data = await api("POST", "/api/save");
    status(`saved ${data.saved}`);
  } catch (err) { status(`error: ${err.message}`); }
}

document.addEventListener("keydown", (ev) => {
  if ($("episode-view").hidden || ev.target === $("label") || ev.target === $("filter")) { return; }
  const step = ev.shiftKey ? 10 : 1;
  const key = ev.key.toLowerCase();
  if (ev.key === "ArrowLeft" || ev.key === "ArrowRight") {
    state.cursor = Math.min(Math.max(state.cursor + (ev.key === "ArrowLeft" ? -step : step), 0), state.rec.num_frames - 1);
    render();
  } else if ((key === "a" || key === "d") && state.handle !== null) {
    snapshot();
    const b = state.handle;
    if (moveBoundary(b, state.rec.segments[b + 1][0] + (key === "a" ? -step : step))) { commit(); } else { state.undo.pop(); }
  } else if (key === "s") { split(); } else if (key === "m") { merge(); } else if (key === "u") { undo(); } else { return; }
  ev.preventDefault();
});

$("label").addEventListener("change", () => { snapshot(); state.rec.instructions[state.sel] = $("label").value; commit(); });
$("reviewed").addEventListener("change", () => { snapshot(); commit(); });
$("scrub").addEventListener("input", () => { state.cursor = Number($("scrub").value); render(); });
$("split").addEventListener("click", split);
$("merge").addEventListener("click", merge);
$("undo").addEventListener("click", undo);
$("save").addEventListener("click", save);
$("back").addEventListener("click", () => { $("episode-view").hidden = true; $("list-view").hidden = false; loadList(); });
$("prev").addEventListener("click", () => { state.page -= 1; loadList(); });
$("next").addEventListener("click", () => { state.page += 1; loadList(); });
$("only").addEventListener("change", () => { state.page = 0; loadList(); });
$("filter").addEventListener("input", () => { state.page = 0; loadList(); });
loadList().catch((err) => status(`error: ${err.message}`));

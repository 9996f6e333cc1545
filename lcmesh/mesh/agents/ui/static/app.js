// lc-mesh operator console: live plots (hand-written canvas), agents, decisions, alerts, chat, controller switch.
// Data: GET /api/history for backfill, then server-sent events from /api/events. No external libraries.
// Cabinets, branches, towers and cells are numbered from 1, as the API sends them.
"use strict";

const MAX_POINTS = 600;
const COLORS = ["#58a6ff", "#f78166", "#3fb950", "#d2a8ff", "#e3b341", "#79c0ff", "#ff7b72", "#56d364", "#bc8cff", "#f2cc60"];
const series = { blades: new Map(), power: new Map(), setpoints: new Map() };
let system = null;
let lastStep = null;
let decisionsSeen = 0;  // decision events received (the feed holds fewer rows: unchanged steps share one)

const $ = (id) => document.getElementById(id);
const fmt = (v, d = 1) => (v === null || v === undefined || Number.isNaN(v) ? "–" : Number(v).toFixed(d));
const el = (tag, attrs = {}, text) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
};

function push(group, name, t, v) {
  if (v === null || v === undefined) return;
  let s = series[group].get(name);
  if (!s) { s = []; series[group].set(name, s); }
  if (s.length && s[s.length - 1][0] >= t) return;
  s.push([t, v]);
  if (s.length > MAX_POINTS) s.splice(0, s.length - MAX_POINTS);
}

// --- plotting: one function, lines against plant time (hours), optional horizontal band -------------------
// opts.bounds = [low, high] (null: open) keeps the y axis inside what the quantity can be: power >= 0 kW,
// fractions in 0..1. The axis drawn is left on the canvas (data-ymin, data-ymax) for tests.
function plot(canvas, group, opts = {}) {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.height / (canvas._dpr || 1);
  if (canvas.width !== Math.round(w * dpr)) { canvas._dpr = dpr; canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  const lines = [...series[group].entries()];
  let x0 = Infinity, x1 = -Infinity, y0 = Infinity, y1 = -Infinity;
  for (const [, pts] of lines) for (const [x, y] of pts) { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); }
  if (opts.band) { y0 = Math.min(y0, opts.band[0] - 1); y1 = Math.max(y1, opts.band[1] + 1); }
  const L = 44, R = 8, T = 8, B = 36;
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillStyle = "#8a9aab";
  if (!Number.isFinite(x0)) { ctx.fillText("waiting for data ...", L, T + 20); return; }
  if (x1 === x0) x1 = x0 + 1e-3;
  if (y1 - y0 < 1e-6) { y0 -= 1; y1 += 1; }
  const pad = (y1 - y0) * 0.06; y0 -= pad; y1 += pad;
  [y0, y1] = withinBounds(y0, y1, opts.bounds);
  canvas.dataset.ymin = y0; canvas.dataset.ymax = y1;
  const X = (x) => L + (x - x0) / (x1 - x0) * (w - L - R);
  const Y = (y) => T + (1 - (y - y0) / (y1 - y0)) * (h - T - B);
  if (opts.band) {
    ctx.fillStyle = "rgba(63,185,80,0.08)";
    ctx.fillRect(L, Y(opts.band[1]), w - L - R, Y(opts.band[0]) - Y(opts.band[1]));
  }
  ctx.strokeStyle = "#2a3541"; ctx.fillStyle = "#8a9aab"; ctx.lineWidth = 1;
  for (let i = 0; i <= 4; i++) {
    const y = y0 + (y1 - y0) * i / 4;
    ctx.beginPath(); ctx.moveTo(L, Y(y)); ctx.lineTo(w - R, Y(y)); ctx.stroke();
    ctx.fillText(fmt(y, Math.abs(y1 - y0) < 10 ? 1 : 0), 4, Y(y) + 4);
  }
  for (let i = 0; i <= 4; i++) {
    const x = x0 + (x1 - x0) * i / 4;
    ctx.textAlign = i === 0 ? "left" : i === 4 ? "right" : "center";
    ctx.fillText(fmt(x, 2) + " h", X(x), h - B + 14);
  }
  ctx.textAlign = "left";
  let lx = L;
  lines.forEach(([name, pts], k) => {
    ctx.strokeStyle = COLORS[k % COLORS.length]; ctx.lineWidth = 1.5;
    ctx.beginPath();
    pts.forEach(([x, y], i) => (i ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.stroke();
    ctx.fillStyle = ctx.strokeStyle;
    ctx.fillRect(lx, h - 12, 10, 3);
    ctx.fillText(name, lx + 13, h - 7);
    lx += ctx.measureText(name).width + 28;
  });
}

// [y0, y1] clipped to bounds = [low, high] (either null), still a span of at least 1 unit
function withinBounds(y0, y1, bounds) {
  const [low, high] = bounds || [null, null];
  if (low !== null && y0 < low) { y0 = low; y1 = Math.max(y1, low + 1); }
  if (high !== null && y1 > high) { y1 = high; y0 = Math.min(y0, high - 1); }
  return [y0, y1];
}

function redraw() {
  plot($("plot-blades"), "blades", { band: [20, 40] });
  plot($("plot-power"), "power", { bounds: [0, null] });
  plot($("plot-setpoints"), "setpoints");
}

// --- state --------------------------------------------------------------------------------------------
function onState(s) {
  if (!s) return;
  const t = s.time_s / 3600;
  s.cabinets.forEach((c) => {
    push("blades", `cab ${c.cabinet}`, t, c.blade_temp_max_c);
    push("setpoints", `supply ${c.cabinet}`, t, c.supply_setpoint_c);
  });
  s.towers.forEach((tw) => push("setpoints", `lw ${tw.tower}`, t, tw.leaving_setpoint_c));
  push("power", "tower fans", t, s.totals.ct_fan_power_kw);
  push("power", "pumps", t, s.totals.pump_power_kw);
  $("step").textContent = s.step;
  $("plant-time").textContent = fmt(t, 2) + " h";
  const hot = s.cabinets.reduce((a, b) => (b.blade_temp_max_c > a.blade_temp_max_c ? b : a));
  $("hottest").textContent = `${fmt(hot.blade_temp_max_c)} °C (cabinet ${hot.cabinet})`;
  $("in-band").textContent = fmt(s.totals.blade_in_band_pct) + " %";
  $("it-power").textContent = fmt(s.totals.it_power_kw) + " kW";
  $("fan-power").textContent = fmt(s.totals.ct_fan_power_kw) + " kW";
  $("pump-power").textContent = fmt(s.totals.pump_power_kw) + " kW";
  $("pue").textContent = fmt(s.totals.cooling_pue, 3);
  $("approach").textContent = s.towers.map((tw) => `tower ${tw.tower}: ${fmt(tw.approach_k)} K`).join(" · ");
  renderWetBulb(s);
  if (s.controller) {
    $("acting").textContent = s.controller.source + (s.controller.fallback ? " (fallback)" : "");
    const who = s.controller.decided_by;  // a controller that falls back says who made its decisions and why not
    const wrote = s.controller.explained_by;  // with the LLM explaining: who wrote the published explanations
    $("decided-by").textContent = [who && `(${who.summary})`, wrote && `(explanations: ${wrote.summary})`]
      .filter(Boolean).join(" ");
  }
  renderSupply(s);
  renderValves(s);
  lastStep = s.step;
}

// The wet bulb the plant runs on; when a scenario shifts or replaces the recorded one, the label says so.
function renderWetBulb(s) {
  const cell = $("wet-bulb");
  cell.textContent = `${fmt(s.wet_bulb_c)} °C` + (s.wet_bulb_note ? ` (${s.wet_bulb_note})` : "");
  cell.classList.toggle("shifted", Boolean(s.wet_bulb_note));
  cell.title = s.wet_bulb_note ? "not the recorded weather: the scenario's wet bulb, which the plant runs on" : "";
}

// Each CDU's measured supply (its sensor, which its valve loop follows) next to the setpoint in force.
function renderSupply(s) {
  const body = $("supply").querySelector("tbody");
  body.replaceChildren();
  s.cabinets.forEach((c) => {
    const off = c.supply_temp_measured_c - c.supply_setpoint_c;
    const tr = el("tr");
    tr.append(el("td", {}, `${c.cabinet}`), el("td", { class: "num measured" }, fmt(c.supply_temp_measured_c)),
      el("td", { class: "num setpoint" }, fmt(c.supply_setpoint_c)),
      el("td", { class: Math.abs(off) > 0.5 ? "num off" : "num" }, (off > 0 ? "+" : "") + fmt(off, 2)),
      el("td", { class: "num" }, fmt(c.blade_temp_max_c)));
    body.append(tr);
  });
}

function renderValves(s) {
  const box = $("valves");
  box.replaceChildren();
  s.cabinets.forEach((c) => {
    const row = el("div", { class: "valve-row" });
    row.append(el("span", { class: "label" }, `cabinet ${c.cabinet}`));
    const bar = el("div", { class: "valve-bar" });
    c.valve_fractions.forEach((v, j) => {
      const part = el("span", {}, fmt(v, 2));
      part.style.width = `${(v * 100).toFixed(1)}%`;  // CSSOM, not a style attribute: allowed by the page's CSP
      part.style.background = COLORS[j % COLORS.length];
      part.title = `branch ${j + 1}: ${fmt(v, 3)}`;
      bar.append(part);
    });
    row.append(bar);
    box.append(row);
  });
}

// --- agents, decisions, alerts -------------------------------------------------------------------------
function renderAgents(rows) {
  const body = $("agents").querySelector("tbody");
  body.replaceChildren();
  rows.forEach((a) => {
    const tr = el("tr");
    tr.append(el("td", {}, a.agent_id), el("td", {}, a.role));
    tr.append(el("td", { class: a.alive ? "up" : "down" }, a.alive ? "up" : "down"));
    tr.append(el("td", { class: "num" }, fmt(a.cpu_pct, 0)), el("td", { class: "num" }, a.rss_bytes ? fmt(a.rss_bytes / 1048576, 0) : "–"));
    tr.append(el("td", { class: "num" }, a.msgs_in));
    if (a.advice && a.advice.length) tr.title = a.advice.join("\n");
    body.append(tr);
  });
}

const explanations = new Map();
const writtenBy = new Map();  // decision id -> "llm" | "renderer": who wrote the explanation's text
const whyRenderer = new Map();  // decision id -> why the rendering stood in for the LLM's text
const llmPart = new Map();  // decision id -> "what-if": the rendering, then the LLM's checked WHAT IF section
const stepOf = new Map();  // decision id -> step, to say which step of a joined row a text explains
// "explanation (who wrote it)"; "explanation of step N (...)" where the text is another step's of a joined row
function explainLabel(id, ofStep) {
  const head = ofStep === undefined ? "explanation" : `explanation of step ${ofStep}`;
  return writtenBy.get(id) === "llm" ? (llmPart.get(id) === "what-if"
    ? `${head} (rendered from the facts; WHAT IF written by the LLM, checked)`
    : `${head} (written by the LLM, checked)`)
    : whyRenderer.get(id) ? `${head} (rendered from the facts: ${whyRenderer.get(id)})`
    : writtenBy.has(id) ? `${head} (rendered from the facts)` : head;
}

// A decision that moved nothing the page shows (`changes` is [], not null: null means no decision before it known)
const unchanged = (d) => Array.isArray(d.changes) && d.changes.length === 0;
// Decisions alike but for their step: same source, fallback and clamps (what a collapsed row stands for)
const decisionKey = (d) => JSON.stringify([d.source_controller, d.source_version, d.fallback, d.fallback_reason,
  (d.clamps || []).map((c) => [c.field, c.index])]);

// One row: the step (or the steps it stands for, with their count), what changed, source, clamps, explanation.
// A joined row's members are the decisions it stands for: where the newest has only the rendering and an earlier
// one has the LLM's text, the row shows that text, labelled with its step.
function decisionItem(d, count = 1, firstStep = d.step, members = [d.decision_id]) {
  const li = el("li", { class: unchanged(d) ? "unchanged" : "changed" });
  Object.assign(li.dataset, { decision: d.decision_id || "", key: decisionKey(d), count, first: firstStep,
    members: members.filter(Boolean).join(" ") });
  const head = el("div");
  head.append(el("span", { class: "tag" }, count > 1 ? `steps ${firstStep}–${d.step}` : `step ${d.step}`));
  if (count > 1) head.append(el("span", { class: "tag count" }, `×${count}`));
  head.append(el("span", { class: "tag" }, `${d.source_controller} v${d.source_version}`));
  if (d.fallback) head.append(el("span", { class: "tag fallback" }, "fallback"));
  const clamps = d.clamps || [];
  if (clamps.length) {
    const tag = el("span", { class: "tag clamp" }, `${clamps.length} clamp(s)`);
    tag.title = clamps.map((c) => `${c.field} [${c.index.join(", ")}]: ${c.reason}`).join("\n");
    head.append(tag);
  }
  if (d.fallback_reason) head.append(el("span", { class: "muted" }, d.fallback_reason));
  li.append(head);
  if (d.changes) {
    const what = d.changes.length ? d.changes.join(", ") : count > 1 ? "no change on these steps" : "no change";
    li.append(el("div", { class: d.changes.length ? "change" : "change muted" }, what));
  }
  if (d.explanation_written_by) rememberWriter({ decision_id: d.decision_id, written_by: d.explanation_written_by,
    why_renderer: d.explanation_why_renderer, llm_part: d.explanation_llm_part });
  let shown = d.decision_id;
  if (writtenBy.get(shown) !== "llm") {
    shown = [...members].reverse().find((id) => writtenBy.get(id) === "llm" && explanations.has(id)) || shown;
  }
  const text = shown === d.decision_id ? d.explanation || explanations.get(shown) : explanations.get(shown);
  if (text) showExplanation(li, shown, text);
  return li;
}

// Put a decision's text in its row (a <details> made on first use), labelled with who wrote it
function showExplanation(li, id, text) {
  let det = li.querySelector("details");
  if (!det) {
    det = el("details");
    det.append(el("summary"), el("pre"));
    li.append(det);
  }
  det.querySelector("summary").textContent = explainLabel(id, id === li.dataset.decision ? undefined : stepOf.get(id));
  det.querySelector("pre").textContent = text;
  li.dataset.shown = id;
}

// Newest on top; an unchanged step like the unchanged row on top joins that row (its count and step range)
// instead of adding an identical row every control period.
function addDecision(d) {
  const list = $("decisions");
  const top = list.firstElementChild;
  if (d.decision_id) {
    stepOf.set(d.decision_id, d.step);
    if (stepOf.size > 400) stepOf.delete(stepOf.keys().next().value);
  }
  if (unchanged(d) && top && top.classList.contains("unchanged") && top.dataset.key === decisionKey(d)) {
    const members = [...top.dataset.members.split(" ").filter(Boolean), d.decision_id].slice(-200);
    top.replaceWith(decisionItem(d, Number(top.dataset.count) + 1, Number(top.dataset.first), members));
    return;
  }
  list.prepend(decisionItem(d));
  while (list.children.length > 60) list.lastChild.remove();
}

// who wrote an explanation (from the stream's explanation event or a /api/decisions row), for its label
function rememberWriter(x) {
  if (x.written_by) writtenBy.set(x.decision_id, x.written_by);
  if (x.why_renderer) whyRenderer.set(x.decision_id, x.why_renderer);
  if (x.llm_part) llmPart.set(x.decision_id, x.llm_part);
}

function addExplanation(x) {
  explanations.set(x.decision_id, x.text);
  rememberWriter(x);
  if (explanations.size > 200) {
    const oldest = explanations.keys().next().value;
    explanations.delete(oldest);
    writtenBy.delete(oldest);
    whyRenderer.delete(oldest);
    llmPart.delete(oldest);
  }
  // the row that stands for this decision: its own, or a joined row of unchanged steps it is a member of
  const li = document.querySelector(`#decisions li[data-members~="${CSS.escape(x.decision_id)}"]`);
  if (!li) return;
  const own = li.dataset.decision === x.decision_id;
  const shownByLlm = li.dataset.shown !== undefined && writtenBy.get(li.dataset.shown) === "llm";
  // the LLM's text goes over a rendering, or over an earlier step's LLM text in a joined row, but not over the
  // row's own LLM text; a rendering goes only in its own row, and not over another step's LLM text
  const rowOwnByLlm = shownByLlm && li.dataset.shown === li.dataset.decision;
  if (x.written_by === "llm" ? !own && rowOwnByLlm : !own || (shownByLlm && li.dataset.shown !== x.decision_id)) {
    return;
  }
  showExplanation(li, x.decision_id, x.text);
}

const alerts = new Map();
function renderAlerts() {
  const list = $("alerts");
  list.replaceChildren();
  const active = [...alerts.values()].filter((a) => a.state === "raised");
  if (!active.length) list.append(el("li", { class: "muted" }, "none active"));
  active.reverse().forEach((a) => {
    const li = el("li");
    li.append(el("span", { class: `tag ${a.severity}` }, a.severity), el("b", {}, `${a.kind} `),
      el("span", {}, `${place(a.location)} ${a.message}`));
    if (a.prescription) li.append(el("div", { class: "muted" }, a.prescription));
    list.append(li);
  });
}

// An alert location as words: "cabinet_3" -> "cabinet 3", "tower_1/cell_2" -> "tower 1, cell 2" (numbered from 1)
const place = (location) => (location || "").replaceAll("/", ", ").replaceAll("_", " ");

function onConfig(doc) {
  if (!doc) return;
  $("config").textContent = `v${doc.version}: ${doc.config.controller}, ${doc.config.mode}`;
  $("controller-select").value = doc.config.controller;
  $("mode-select").value = doc.config.mode;
}

// --- live events ----------------------------------------------------------------------------------------
function connect() {
  const source = new EventSource("/api/events");
  const on = (name, fn) => source.addEventListener(name, (e) => { try { fn(JSON.parse(e.data)); } catch (err) { console.error(name, err); } });
  source.onopen = () => { $("conn").textContent = "live"; $("conn").className = "pill pill-on"; };
  source.onerror = () => { $("conn").textContent = "reconnecting"; $("conn").className = "pill pill-off"; };
  on("hello", (h) => {
    system = h.system;
    $("site").textContent = `${h.system.name}`;
    onState(h.state);
    renderAgents(h.agents);
    $("decisions").replaceChildren();
    [...h.decisions].reverse().forEach(addDecision);  // oldest first, so alike unchanged steps collapse
    h.alerts.forEach((a) => alerts.set(a.alert_id, a));
    renderAlerts();
    onConfig(h.config);
    redraw();
  });
  on("state", (s) => { onState(s); redraw(); });
  on("decision", (d) => { decisionsSeen += 1; addDecision(d); });
  on("explanation", addExplanation);
  on("alert", (a) => { alerts.set(a.alert_id, a); renderAlerts(); });
  on("agents", renderAgents);
  on("config", onConfig);
}

async function backfill() {
  try {
    const r = await fetch("/api/history?last_s=3600&max_points=400&fields=blade_temp_max_c,ct_fan_power_kw,pump_power_kw");
    if (!r.ok) return;
    const h = await r.json();
    h.rows.forEach((row) => {
      const t = row.time_s / 3600;
      push("blades", "plant max", t, row.blade_temp_max_c);
      push("power", "tower fans", t, row.ct_fan_power_kw);
      push("power", "pumps", t, row.pump_power_kw);
    });
    redraw();
  } catch (err) { console.warn("history backfill failed", err); }
}

// --- writes: controller switch and confirmed chat commands (need the token) ----------------------------------
function token() {
  const t = $("token").value.trim();
  if (t) sessionStorage.setItem("lcmesh-token", t);
  return t || sessionStorage.getItem("lcmesh-token") || "";
}

async function send(method, path, body) {
  const r = await fetch(path, { method, headers: { "Content-Type": "application/json", Authorization: `Bearer ${token()}` }, body: JSON.stringify(body) });
  const data = await r.json().catch(() => ({}));
  if (!r.ok) throw new Error(`${r.status}: ${data.detail || r.statusText}`);
  return data;
}

$("mode-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  $("mode-result").textContent = "...";
  try {
    const d = await send("POST", "/api/control/mode", { controller: $("controller-select").value, mode: $("mode-select").value, reason: "web console" });
    $("mode-result").textContent = `v${d.config_version}: ${d.controller}, ${d.mode}`;
  } catch (err) { $("mode-result").textContent = err.message; }
});

// --- chat -------------------------------------------------------------------------------------------------
function showAnswer(d) {
  const box = el("div", { class: d.declined ? "chat-answer declined" : "chat-answer" });
  box.append(el("div", { class: "answer-text" }, d.answer));
  if (d.declined) {  // an answer to a neighbouring question is not shown as the answer
    box.append(el("div", { class: "muted declined-note" }, `not an answer: the question asks for ${(d.missing || []).join(", ")}`));
  }
  (d.detail || []).forEach((x) => {  // a decision's whole reasoning, behind a click
    const more = el("details", { class: "answer-detail" });
    more.append(el("summary", { class: "muted" }, `the whole reasoning: ${x.title}`), el("div", {}, x.text));
    box.append(more);
  });
  if (d.facts && d.facts.length) {
    const det = el("details");
    const about = [`${d.facts.length} fact(s)`, d.intent, `read by ${d.planned_by}`, d.follow_up ? "follow-up" : "",
      d.plan_note ? `(${d.plan_note})` : "", d.phrased_by,
      d.grounded ? "grounded" : "not grounded", `${fmt(d.elapsed_ms, 0)} ms`];
    det.append(el("summary", { class: "muted" }, about.filter(Boolean).join(" · ")));
    const ul = el("ul", { class: "facts" });
    d.facts.forEach((f) => ul.append(el("li", {}, `${f.name} = ${f.display} (${f.text}; ${f.source})`)));
    det.append(ul);
    box.append(det);
  }
  if (d.proposed_command) {
    const c = d.proposed_command;
    const cmd = el("div", { class: "command" });
    cmd.append(el("div", {}, "Proposed command (not applied):"), el("code", {}, `${c.method} ${c.path} ${JSON.stringify(c.body)}`));
    const ok = el("button", { type: "button" }, "Confirm with token");
    const out = el("span", { class: "muted" });
    ok.addEventListener("click", async () => {
      out.textContent = " sending ...";
      try { const r = await send(c.method, c.path, c.body); out.textContent = ` applied: config v${r.config_version}, ${r.detail}`; }
      catch (err) { out.textContent = ` ${err.message}`; }
    });
    cmd.append(ok, out);
    box.append(cmd);
  }
  return box;
}

// one chat session per page: a follow-up ("and cabinet 2?", "why?") reads the previous question
const chatSession = (crypto.randomUUID ? crypto.randomUUID() : String(Math.random()).slice(2)).replace(/[^A-Za-z0-9_-]/g, "");

$("chat-form").addEventListener("submit", async (e) => {
  e.preventDefault();
  const input = $("chat-input");
  const message = input.value.trim();
  if (!message) return;
  const log = $("chat-log");
  log.append(el("div", { class: "q" }, message));
  input.value = "";
  try {
    const r = await fetch("/api/chat", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify({ message, session: chatSession }) });
    const d = await r.json();
    if (!r.ok) { log.append(el("div", { class: "chat-answer error" }, `${r.status}: ${d.detail}`)); }
    else log.append(showAnswer(d));
  } catch (err) { log.append(el("div", { class: "chat-answer error" }, String(err))); }
  log.scrollTop = log.scrollHeight;
});

window.addEventListener("resize", redraw);
backfill().then(connect);

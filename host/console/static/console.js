// skel console's page: draws what the server computes and sends the operator's edits back.
// It analyses nothing itself: the prediction is skel check's, the live figures skel watch's.
"use strict";

const SVG = "http://www.w3.org/2000/svg";
const MIN_SCALE = 0.7;
const elk = new ELK();
const state = { base: null, current: null, edits: {}, seq: 0, live: null, picked: new Set(), direction: null };

function $(id) { return document.getElementById(id); }
function el(tag, attrs = {}, text) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}
function svg(tag, attrs = {}, text) {
  const node = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}
async function call(method, path, body) {
  const response = await fetch(path, { method, headers: { "Content-Type": "application/json" },
                                       body: body === undefined ? undefined : JSON.stringify(body) });
  let data = null;
  try { data = await response.json(); } catch (e) { data = { ok: false, error: await response.text() }; }
  return { status: response.status, data };
}
function fmt(v, digits = 1) { return v === null || v === undefined ? "-" : Number(v).toFixed(digits); }

// --- the picture (the paper's Figure 8), laid out by ELK ------------------------------------
// Each label is measured in the font it is drawn in (console.css: svg text, .title, .label), so
// ELK gives every box and edge label the room its text takes: none runs out of its box.
const FONTS = { plain: "11px system-ui, sans-serif", title: "bold 11px system-ui, sans-serif",
                label: "10px system-ui, sans-serif" };
const ruler = document.createElement("canvas").getContext("2d");
function textWidth(text, font = "plain") {
  ruler.font = FONTS[font];
  return Math.ceil(ruler.measureText(text).width) + 12;
}

function chainEdges(graph) {
  const pairs = new Set();
  for (const chain of graph.chains)
    for (let i = 0; i + 1 < chain.processes.length; i++) pairs.add(chain.processes[i] + ">" + chain.processes[i + 1]);
  return pairs;
}

function elkGraph(graph, loads, direction) {
  const procNode = (p) => ({ id: "p:" + p.name, height: 36,
                             width: Math.max(120, textWidth(p.name, "title"), textWidth(processLine(p))) });
  // A box at least as wide as its title, which is drawn above its children.
  const titled = (id, title, children) => ({
    id, children, labels: [{ text: title, width: textWidth(title, "title"), height: 14 }],
    layoutOptions: { "elk.padding": "[top=26,left=10,bottom=10,right=10]",
                     "elk.nodeSize.constraints": "MINIMUM_SIZE", "elk.nodeSize.minimum": `(${textWidth(title, "title") + 12}, 40)` } });
  const dpuNode = (d) => titled("d:" + d.id, `DPU ${d.id} · ${fmt(loads[d.id])} %`,
                                graph.processes.filter((p) => p.dpu === d.id).map(procNode));
  const hostNode = (h) => titled("h:" + h.name, "host " + h.name, graph.dpus.filter((d) => d.host === h.name).map(dpuNode));
  const edges = [];
  const sources = [];
  for (const b of graph.buffers) {
    b.readers.forEach((r, i) => {
      const label = `${b.name} ${b.bytes} B · ${fmt(b.rate_hz, 0)} Hz`;
      edges.push({ id: `b:${b.id}:${i}`, sources: ["p:" + b.writer], targets: ["p:" + r.process],
                   labels: i === 0 ? [{ text: label, width: textWidth(label, "label"), height: 12 }] : [] });
    });
  }
  graph.events.forEach((e, k) => {
    e.from.forEach((from, i) => {
      let source = "p:" + from;
      if (!graph.processes.some((p) => p.name === from)) {
        source = `e:${k}:${i}`;
        sources.push({ id: source, width: textWidth(from), height: 24, labels: [{ text: from }] });
      }
      e.to.forEach((to, j) => edges.push({ id: `ev:${k}:${i}:${j}`, sources: [source], targets: ["p:" + to],
                                            labels: [{ text: "event " + e.name, width: textWidth("event " + e.name, "label"), height: 12 }] }));
    });
  });
  return {
    id: "root",
    layoutOptions: { "elk.algorithm": "layered", "elk.direction": direction,
                     "elk.hierarchyHandling": "INCLUDE_CHILDREN", "elk.json.edgeCoords": "ROOT",
                     "elk.json.shapeCoords": "ROOT", "elk.layered.spacing.nodeNodeBetweenLayers": "40",
                     "elk.spacing.edgeLabel": "2", "elk.edgeLabels.inline": "false" },
    children: [...graph.hosts.map(hostNode), ...sources],
    edges,
  };
}

// Left to right, as the paper's Figure 8, when that fits the column at MIN_SCALE; a graph too
// long for it (a long chain of processes) is laid out top to bottom too, kept when that fits: a
// page scrolls down better than sideways. A graph that fits neither way (the 64-DPU ring) stays
// left to right, where the arrows enter the boxes from the side, clear of their titles. The
// direction is chosen once per system loaded: an edit redraws with one layout, the same way round.
async function laidOut(graph, loads) {
  if (state.direction) return elk.layout(elkGraph(graph, loads, state.direction));
  const fits = (laid) => (laid.width + 20) * MIN_SCALE <= $("picture").clientWidth;
  const right = await elk.layout(elkGraph(graph, loads, "RIGHT"));
  state.direction = "RIGHT";
  if (fits(right)) return right;
  const down = await elk.layout(elkGraph(graph, loads, "DOWN"));
  if (!fits(down)) return right;
  state.direction = "DOWN";
  return down;
}

function processLine(p) {
  return `${p.compute_us} / ${p.period_us} µs` + (p.sync === "periodic" ? "" : " · " + p.sync);
}

async function draw(graph, loads) {
  const began = performance.now();
  const laid = await laidOut(graph, loads);
  const root = $("graph");
  root.replaceChildren();
  root.dataset.direction = state.direction;
  // Scaled to the column's width, but never below MIN_SCALE: a large system scrolls, its
  // labels still readable, rather than shrinking to a line.
  const [width, height] = [laid.width + 20, laid.height + 20];
  const scale = Math.max(MIN_SCALE, Math.min(1, $("picture").clientWidth / width));
  root.setAttribute("viewBox", `-10 -10 ${width} ${height}`);
  root.setAttribute("width", width * scale);
  root.setAttribute("height", height * scale);
  const defs = svg("defs");
  for (const [id, color] of [["arrow", "#555"], ["arrow-wait", "#06c"], ["arrow-chain", "#e80"], ["arrow-event", "#93c"]]) {
    const marker = svg("marker", { id, viewBox: "0 0 10 10", refX: 9, refY: 5, markerWidth: 7, markerHeight: 7, orient: "auto" });
    marker.append(svg("path", { d: "M0,0 L10,5 L0,10 z", fill: color }));
    defs.append(marker);
  }
  root.append(defs);
  const chained = chainEdges(graph);
  const inChain = new Set(graph.chains.flatMap((c) => c.processes));
  const box = (node, cls, attrs) => {
    const g = svg("g", { class: cls, ...attrs });
    g.append(svg("rect", { x: node.x, y: node.y, width: node.width, height: node.height }));
    return g;
  };
  for (const host of laid.children.filter((n) => n.id.startsWith("h:"))) {
    const hg = box(host, "host", { "data-host": host.id.slice(2) });
    hg.append(svg("text", { x: host.x + 6, y: host.y + 16, class: "title" }, host.labels[0].text));
    root.append(hg);
    for (const dpu of host.children) {
      const id = Number(dpu.id.slice(2));
      const dg = box(dpu, "dpu" + (loads[id] > 100 ? " over" : ""), { "data-dpu": id, "data-host": host.id.slice(2) });
      dg.append(svg("text", { x: dpu.x + 6, y: dpu.y + 16, class: "title" }, dpu.labels[0].text));
      root.append(dg);
      for (const proc of dpu.children) {
        const p = graph.processes.find((q) => "p:" + q.name === proc.id);
        const pg = box(proc, "process" + (inChain.has(p.name) ? " in-chain" : ""), { "data-process": p.name, "data-dpu": id });
        pg.append(svg("text", { x: proc.x + 6, y: proc.y + 15, class: "title" }, p.name));
        pg.append(svg("text", { x: proc.x + 6, y: proc.y + 29 }, processLine(p)));
        pg.addEventListener("pointerdown", (event) => { event.preventDefault(); state.dragging = p; });
        root.append(pg);
      }
    }
  }
  for (const source of laid.children.filter((n) => n.id.startsWith("e:"))) {
    const sg = box(source, "event-source", {});
    sg.append(svg("text", { x: source.x + 4, y: source.y + 16 }, source.labels[0].text));
    root.append(sg);
  }
  const groups = {};
  for (const edge of laid.edges) {
    const [kind, ident, index] = edge.id.split(":");
    const path = (edge.sections || []).map((s) =>
      "M" + [s.startPoint, ...(s.bendPoints || []), s.endPoint].map((pt) => `${pt.x},${pt.y}`).join(" L")).join(" ");
    let cls = "";
    let marker = "arrow";
    if (kind === "b") {
      const b = graph.buffers.find((x) => String(x.id) === ident);
      const reader = b.readers[Number(index)];
      if (chained.has(b.writer + ">" + reader.process)) { cls = "chain"; marker = "arrow-chain"; }
      else if (reader.waits) { cls = "wait"; marker = "arrow-wait"; }
      if (reader.waits) cls += " wait";
      const key = "b" + ident;
      if (!groups[key]) {
        groups[key] = svg("g", { class: "buffer", "data-buffer": b.name });
        root.append(groups[key]);
      }
      groups[key].append(svg("path", { d: path, class: cls.trim(), "marker-end": `url(#${marker})`,
                                       "data-reader": reader.process, "data-writer": b.writer }));
      for (const label of edge.labels || [])
        groups[key].append(svg("text", { x: label.x, y: label.y + 10, class: "label" }, label.text));
    } else {
      const g = svg("g", { class: "event" });
      g.append(svg("path", { d: path, "marker-end": "url(#arrow-event)" }));
      for (const label of edge.labels || []) g.append(svg("text", { x: label.x, y: label.y + 10, class: "label" }, label.text));
      root.append(g);
    }
  }
  document.body.dataset.layoutMs = String(Math.round(performance.now() - began));
}

// A process dragged onto another DPU (its box, or a process in it) is allocated there: the same
// edit as choosing that DPU in its row. A press without a move selects it.
document.addEventListener("pointerup", (event) => {
  const p = state.dragging;
  state.dragging = null;
  if (!p) return;
  const onto = document.elementFromPoint(event.clientX, event.clientY)?.closest("#graph [data-dpu]");
  const dpu = onto ? Number(onto.dataset.dpu) : p.dpu;
  if (dpu === p.dpu) { select(p.name); return; }
  const field = $(`edit-process-${p.name}-dpu`);
  field.value = String(dpu);
  edited(field);
});

function select(name) {
  document.querySelectorAll("#graph .process").forEach((g) => g.classList.toggle("selected", g.dataset.process === name));
  const input = $(`edit-process-${name}-compute_us`);
  if (input) { input.focus(); input.scrollIntoView({ block: "nearest" }); }
}

// --- the descriptors, editable ---------------------------------------------------------------
function editor(target, value, options) {
  const id = "edit-" + target.replaceAll(".", "-");
  let input;
  if (options) {
    input = el("select", { id, "data-target": target });
    for (const o of options) input.append(el("option", { value: o }, o));
    input.value = String(value);
  } else {
    input = el("input", { id, "data-target": target, type: "number", value });
  }
  input.dataset.original = String(value);
  input.addEventListener("change", () => edited(input));
  return input;
}

function edited(input) {
  const target = input.dataset.target;
  const raw = input.value;
  if (raw === "") return;  // a field being retyped: nothing to predict yet
  if (raw === input.dataset.original) delete state.edits[target];
  else state.edits[target] = input.type === "number" || /^\d+$/.test(raw) ? Number(raw) : raw;
  input.classList.toggle("changed", target in state.edits);
  repredict();
}

function descriptors(graph) {
  const rows = $("processes").tBodies[0];
  rows.replaceChildren();
  const dpuIds = graph.dpus.map((d) => String(d.id));
  for (const p of graph.processes) {
    const tr = el("tr", { "data-process": p.name });
    tr.append(el("td", {}, p.name));
    for (const [field, value, options] of [["dpu", p.dpu, dpuIds], ["compute_us", p.compute_us],
                                           ["period_us", p.period_us], ["sync", p.sync, ["periodic", "data", "event"]]]) {
      const td = el("td");
      td.append(editor(`process.${p.name}.${field}`, value, options));
      tr.append(td);
    }
    rows.append(tr);
  }
  const buffers = $("buffers").tBodies[0];
  buffers.replaceChildren();
  for (const b of graph.buffers) {
    const tr = el("tr", { "data-buffer": b.name });
    tr.append(el("td", {}, b.name));
    const td = el("td");
    td.append(editor(`buffer.${b.name}.bytes`, b.bytes));
    tr.append(td);
    tr.append(el("td", {}, `${b.writer} → ${b.readers.map((r) => r.process + (r.waits ? " (waits)" : "")).join(", ") || "nobody"}`));
    buffers.append(tr);
  }
  $("cycles").replaceChildren(editor("run.cycles", graph.run.cycles ?? ""));
  const chain = (c) => c.processes.join(" → ") + (c.name === c.processes.join("->") ? "" : ` (${c.name})`);
  $("chains").replaceChildren(...graph.chains.map((c) => el("span", { title: "chain" }, chain(c))));
}

// --- the prediction, as skel check gives it ----------------------------------------------------
function loadsOf(summary) {
  const out = {};
  for (const d of summary.prediction.dpus) out[d.id] = d.load_pct;
  return out;
}

async function showPrediction(result) {
  const error = $("error");
  const invalid = !result.ok;
  error.hidden = !invalid;
  error.textContent = invalid ? result.error : "";
  for (const id of ["push", "run", "save"]) $(id).disabled = invalid;
  $("prediction").classList.toggle("stale", invalid);
  if (invalid) return;
  state.current = result;
  const base = loadsOf(state.base.summary);
  const body = $("prediction").tBodies[0];
  body.replaceChildren();
  for (const d of result.summary.prediction.dpus) {
    const tr = el("tr", { id: `predict-dpu-${d.id}`, "data-dpu": d.id });
    tr.append(el("td", {}, String(d.id)));
    tr.append(el("td", { class: "load" + (d.load_pct > 100 ? " over" : "") }, fmt(d.load_pct)));
    tr.append(el("td", { class: "base" }, fmt(base[d.id])));
    tr.append(el("td", {}, d.schedulable ? "yes" : "NO" + (d.lockout_ms ? ` (lockout ${fmt(d.lockout_ms)} ms)` : "")));
    tr.append(el("td", { class: "live" }, liveCell(d.id)));
    body.append(tr);
  }
  $("warnings").replaceChildren(...result.summary.warnings.map((w) => el("li", {}, "WARN " + w)));
  const row = (cells) => { const tr = el("tr"); for (const c of cells) tr.append(el("td", {}, String(c))); return tr; };
  $("responses").tBodies[0].replaceChildren(...result.summary.prediction.processes.map((p) =>
    row([p.name, p.dpu, p.response_us === null ? "unbounded" : fmt(p.response_us, 0), p.paced_by ?? "-"])));
  $("chain-bounds").tBodies[0].replaceChildren(...result.summary.prediction.chains.map((c) =>
    row([c.processes.join(" → "), fmt(c.best_us, 0), c.worst_us === null ? "unbounded" : fmt(c.worst_us, 0)])));
  const changed = Object.entries(state.edits).map(([k, v]) => `${k}=${v}`);
  $("changes").textContent = changed.length ? "edits: " + changed.join(", ") : "no edits";
  await draw(result.graph, loadsOf(result.summary));
  markFaults();
}

async function repredict() {
  const seq = ++state.seq;
  const { data } = await call("POST", "/api/predict", { set: state.edits });
  if (seq !== state.seq) return;  // a newer edit's answer wins
  await showPrediction(data);
  if (seq === state.seq) document.body.dataset.settled = String(seq);
}

// --- push, run, save: skel push, skel run, the file rewritten ---------------------------------
async function job(path, body) {
  const { status, data } = await call("POST", path, body);
  if (status >= 400) { $("job").textContent = data.error; return; }
  followAfter(0);
}

let followTimer = null;
function followAfter(ms) { clearTimeout(followTimer); followTimer = setTimeout(follow, ms); }

// The commands running (a run, and a push into it) and the last one started, each as a terminal
// shows it, until none runs.
async function follow() {
  const { data } = await call("GET", "/api/job");
  $("job").replaceChildren(...data.map((j, i) => el("span", {
    class: "job", "data-kind": j.kind, "data-running": j.running, "data-returncode": j.returncode ?? "",
    "data-out": j.out ?? "" }, (i ? "\n\n" : "") + `$ ${j.command}\n${j.output.join("\n")}` +
    (j.running ? "\n…" : `\n(exit ${j.returncode})`))));
  if (data.some((j) => j.running)) { followAfter(500); return; }
  const last = data[data.length - 1];
  if (last && last.kind === "report") showPlots(last.out);
  else notebook();
}

async function save() {
  const { status, data } = await call("POST", "/api/save", { set: state.edits });
  $("job").textContent = status >= 400 ? data.error : `saved ${data.saved} (${data.edits.join(", ") || "no edits"})`;
  if (status < 400) start();
}

// --- live: skel watch's tables, streamed ---------------------------------------------------------
function liveCell(dpu) {
  const row = state.live && (state.live.dpus || []).find((d) => d.id === dpu);
  return row ? `${fmt(row.compute_pct)} / ${fmt(row.communicate_pct)} / ${fmt(row.wait_pct)}` : "-";
}

function showLive(view) {
  state.live = view;
  const head = view.error ? view.error : !view.listening ? `subscribing to ${view.url}…` :
    view.run_id === null ? `waiting for a run on ${view.url}` :
    `run ${view.run_id}` + (view.system ? ` of ${view.system} · generation ${view.generation}` : "") +
    ` · ${fmt(view.elapsed_s)} s measured (warm-up excluded) · ${view.records ?? 0} records` +
    (view.unsearched ? ` · ${view.unsearched} forgotten before the search for faults read them` : "");
  $("live-head").textContent = head;
  showProgress(view.run_id === null ? null : view.progress);
  document.querySelectorAll("#prediction tr[data-dpu]").forEach((tr) => {
    tr.querySelector(".live").textContent = liveCell(Number(tr.dataset.dpu));
  });
  const body = $("live-processes").tBodies[0];
  body.replaceChildren(...(view.processes || []).map((p) => {
    const tr = el("tr");
    for (const cell of [p.name, p.dpu, p.cycles, p.overruns,
                        `${fmt(p.latency_p50_us)} / ${fmt(p.latency_p99_us)} / ${fmt(p.latency_max_us)}`, `${p.late} / ${p.too_late}`])
      tr.append(el("td", {}, String(cell)));
    return tr;
  }));
  markFaults();
  $("faults").replaceChildren(...(view.faults || []).map((f) => el("li", { class: "over" }, `${f.at_s} s: ${f.text}`)));
}

// How far the run has come: since its cycle 0, in the cycles `run.cycles` counts (warm-up
// included), of its planned length, as the listener has it from the run's START and heartbeats.
function showProgress(progress) {
  const bar = $("run-progress");
  const text = $("progress");
  bar.hidden = !progress || progress.planned_s === null;
  text.dataset.cycle = progress ? progress.cycle : "";
  text.dataset.cycles = progress ? progress.cycles ?? "" : "";
  if (!progress) { text.textContent = ""; return; }
  text.textContent = progress.planned_s === null
    ? `cycle ${progress.cycle} · ${fmt(progress.elapsed_s)} s, until stopped`
    : `cycle ${progress.cycle} of ${progress.cycles} · ${fmt(progress.elapsed_s)} s of ${fmt(progress.planned_s)} s`;
  if (progress.planned_s) bar.value = progress.elapsed_s / progress.planned_s;
}

// A fatal fault on the graph: its chain from the process it struck back to the root cause (a
// lockout's process and the writer it waits on, a jam's chain; each step a reader waiting for its
// writer), as the listener found them; the root cause drawn apart. A DPU's own fault (it ran behind
// its schedule) marks the DPU.
function markFaults() {
  const faults = ((state.live && state.live.faults) || []).filter((f) => f.fatal);
  const procs = new Set(faults.flatMap((f) => [f.process, ...(f.chain || [])]).filter(Boolean));
  const roots = new Set(faults.map((f) => (f.chain || []).at(-1)).filter(Boolean));
  const steps = new Set(faults.flatMap((f) => (f.chain || []).slice(0, -1).map((p, i) => `${f.chain[i + 1]}>${p}`)));
  document.querySelectorAll("#graph .process").forEach((g) => {
    g.classList.toggle("faulty", procs.has(g.dataset.process));
    g.classList.toggle("root-cause", roots.has(g.dataset.process));
  });
  const dpus = new Set(faults.filter((f) => !f.process && f.dpu !== null).map((f) => String(f.dpu)));  // behind
  document.querySelectorAll("#graph .dpu").forEach((g) => g.classList.toggle("faulty", dpus.has(g.dataset.dpu)));
  document.querySelectorAll("#graph .buffer path").forEach((path) =>
    path.classList.toggle("faulty", steps.has(`${path.dataset.writer}>${path.dataset.reader}`)));
}

// --- the notebook: this session's runs, any two compared ----------------------------------------
async function notebook() {
  const { data } = await call("GET", "/api/runs");
  const body = $("runs").tBodies[0];
  body.replaceChildren(...data.map((r) => {
    const tr = el("tr", { "data-out": r.out });
    const tick = el("input", { type: "checkbox" });
    tick.checked = state.picked.has(r.out);
    tick.addEventListener("change", () => { tick.checked ? state.picked.add(r.out) : state.picked.delete(r.out); });
    const td = el("td");
    td.append(tick);
    tr.append(td);
    const figures = r.dpus.map((d) => `${d.id}: ${fmt(d.compute_pct)}`).join(", ");
    for (const cell of [r.started, r.edits.join(", ") || "-", r.running ? "running…" : (r.verdict ?? `exit ${r.returncode}`),
                        figures || "-", r.out])
      tr.append(el("td", {}, cell));
    const plot = el("button", { class: "plot", title: "skel report RUN --plots" }, "Plots");
    plot.addEventListener("click", () => job("/api/plots", { run: r.out }));
    const cell = el("td");
    cell.append(plot);
    tr.append(cell);
    return tr;
  }));
}

async function showPlots(run) {
  const { data } = await call("GET", "/api/plots?run=" + encodeURIComponent(run));
  $("plots").replaceChildren(el("h2", {}, "Plots of " + run), ...data.map((name) =>
    el("img", { src: `/api/plots?run=${encodeURIComponent(run)}&name=${encodeURIComponent(name)}`, alt: name,
                title: name, width: "100%" })));
}

async function compare() {
  const [a, b] = [...state.picked];
  if (state.picked.size !== 2) { $("job").textContent = "tick two runs to compare"; return; }
  job("/api/diff", { a, b });
}

// --- start --------------------------------------------------------------------------------------
async function start() {
  const { data } = await call("GET", "/api/system");
  $("file").textContent = data.file;
  if (!data.ok) { $("error").hidden = false; $("error").textContent = data.error; return; }
  state.base = data;
  state.edits = {};
  state.direction = null;
  $("system-name").textContent = data.summary.system;
  $("status").textContent = `DPUs on ${data.url}` + (data.spawn ? " (Run spawns local DPUs)" : "");
  descriptors(data.graph);
  await showPrediction(data);
  notebook();
}

// Any descriptor, as `-s TARGET=VALUE`: VALUE is read as JSON when it is (3000, [3, 5], {"kind": ...}),
// as YAML's flow mapping when it looks like one, else as the text typed.
$("any-edit").addEventListener("keydown", (event) => {
  if (event.key !== "Enter") return;
  const [target, ...rest] = event.target.value.split("=");
  const raw = rest.join("=").trim();
  let value = raw;
  try { value = JSON.parse(raw); } catch (e) {
    const flow = raw.match(/^\{(.*)\}$/);
    if (flow) value = Object.fromEntries(flow[1].split(",").map((kv) => kv.split(":").map((s) => s.trim()))
      .map(([k, v]) => [k, v !== "" && !isNaN(Number(v)) ? Number(v) : v]));
  }
  state.edits[target.trim()] = raw === "" ? null : value;
  event.target.value = "";
  repredict();
});
$("push").addEventListener("click", () => job("/api/push", { set: state.edits }));
$("run").addEventListener("click", () => job("/api/run", { set: state.edits }));
$("save").addEventListener("click", save);
$("reset").addEventListener("click", start);
$("compare").addEventListener("click", compare);
new EventSource("/api/live").onmessage = (message) => showLive(JSON.parse(message.data));
start().then(() => { document.body.dataset.ready = "1"; });

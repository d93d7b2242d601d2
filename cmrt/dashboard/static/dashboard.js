// The dashboard's pages: each reads the same JSON endpoints a script would (/api/...), and draws it with
// plotly (served from the plotly Python package; no CDN, no build step). Plain ES2017, no framework.
"use strict";

const POLL_MS = 2000; // while a run is queued or running, its data is read again this often

async function getJSON(url) {
  const response = await fetch(url);
  const body = await response.json();
  if (!response.ok) throw new Error(body.error || response.statusText);
  return body;
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") node.className = v; else node.setAttribute(k, v);
  }
  for (const c of children) node.append(c instanceof Node ? c : document.createTextNode(c));
  return node;
}

function num(x, digits = 4) {
  if (x === null || x === undefined) return "-";
  return Math.abs(x) < 1e-12 ? "0" : Number(x).toPrecision(digits); // a margin of 8e-17 m is 0
}

function verdictCell(success, fell) {
  if (success === null || success === undefined) return el("span", { class: "muted" }, "-");
  if (success) return el("span", { class: "ok" }, "SUCCESS");
  return el("span", { class: "bad" }, fell ? "fell" : "no");
}

function robustnessText(r) {
  if (!r) return "-";
  return `${r.validation_survived}/${r.validation_total}`;
}

function statusCell(run) {
  const p = run.progress;
  const cell = el("span", { class: `status-${run.status}` }, run.status);
  if (run.status === "running" && p.fraction !== null) {
    const bar = el("span", { class: "bar", title: `${p.evaluations} of ${p.max_evals} evaluations` },
      el("span", { style: `width:${(100 * p.fraction).toFixed(1)}%` }));
    return el("span", {}, cell, bar, ` ${p.evaluations}/${p.max_evals}, gen ${p.generations}`);
  }
  if (run.status === "failed" && run.error) cell.title = run.error;
  return cell;
}

const PLOT_CONFIG = { responsive: true, displaylogo: false };
const AXIS = { zeroline: false, gridcolor: "#eee" };

function layout(extra) {
  return Object.assign({ margin: { l: 60, r: 20, t: 30, b: 45 }, legend: { font: { size: 11 } },
    plot_bgcolor: "#fff", paper_bgcolor: "#fff" }, extra);
}

// --- the runs table ------------------------------------------------------------------------------
const table = { rows: [], key: "id", dir: 1 };

function sortValue(row, key) {
  if (key === "robustness") return row.robustness ? row.robustness.validation_survived : null;
  const v = row[key];
  return v === true ? 1 : v === false ? 0 : v;
}

function drawRuns() {
  const text = document.getElementById("filter").value.trim().toLowerCase();
  const status = document.getElementById("status").value;
  const rows = table.rows.filter((r) => (!status || r.status === status) && (!text || [
    r.id, r.task, r.speed, r.reference, r.status, r.stop_reason].join(" ").toLowerCase().includes(text)));
  rows.sort((a, b) => {
    const x = sortValue(a, table.key), y = sortValue(b, table.key);
    if (x === y) return a.id - b.id;
    if (x === null || x === undefined) return 1;
    if (y === null || y === undefined) return -1;
    return (x < y ? -1 : 1) * table.dir;
  });
  const body = document.querySelector("#runs tbody");
  const checked = new Set([...body.querySelectorAll("input:checked")].map((c) => c.value));
  body.replaceChildren(...rows.map((r) => {
    const box = el("input", { type: "checkbox", value: r.id, "aria-label": `select run ${r.id}` });
    box.checked = checked.has(String(r.id));
    box.addEventListener("change", updateCompare);
    return el("tr", { "data-run": r.id },
      el("td", {}, box),
      el("td", {}, el("a", { href: `/runs/${r.id}` }, `run ${r.id}`)),
      el("td", {}, r.task), el("td", { class: "num" }, r.speed === null ? "-" : String(r.speed)),
      el("td", {}, r.reference), el("td", {}, statusCell(r)),
      el("td", { class: "num" }, num(r.best_objective)), el("td", {}, verdictCell(r.best_success, r.best_fell)),
      el("td", { class: "num" }, num(r.baseline_objective)), el("td", { class: "num" }, num(r.improvement_over_zero)),
      el("td", { title: "perturbed validation clips that succeed" }, robustnessText(r.robustness)),
      el("td", { class: "num" }, String(r.evaluations)));
  }));
  document.getElementById("empty").hidden = rows.length > 0;
  for (const th of document.querySelectorAll("#runs th[data-key]")) {
    th.classList.toggle("asc", th.dataset.key === table.key && table.dir > 0);
    th.classList.toggle("desc", th.dataset.key === table.key && table.dir < 0);
  }
  updateCompare();
}

function updateCompare() {
  const ids = [...document.querySelectorAll("#runs tbody input:checked")].map((c) => c.value);
  const button = document.getElementById("compare");
  button.disabled = ids.length < 1;
  button.onclick = () => { window.location.href = `/compare?runs=${ids.join(",")}`; };
}

async function refreshRuns() {
  const live = document.getElementById("live");
  try {
    const data = await getJSON("/api/runs");
    table.rows = data.runs;
    document.getElementById("store").textContent = data.store;
    live.textContent = data.active ? `live: a run is queued or running (read every ${POLL_MS / 1000} s)` : "";
    drawRuns();
    if (data.active) setTimeout(refreshRuns, POLL_MS);
  } catch (err) {
    live.textContent = `cannot read the store: ${err.message}`;
    live.className = "error";
  }
}

function runsPage() {
  document.getElementById("filter").addEventListener("input", drawRuns);
  document.getElementById("status").addEventListener("change", drawRuns);
  for (const th of document.querySelectorAll("#runs th[data-key]")) {
    th.addEventListener("click", () => {
      table.dir = table.key === th.dataset.key ? -table.dir : 1;
      table.key = th.dataset.key;
      drawRuns();
    });
  }
  refreshRuns();
}

// --- a run -------------------------------------------------------------------------------------------
function runId() {
  return Number(window.location.pathname.split("/").pop());
}

function definitionRows(def, prefix = "") {
  // a task definition as rows of name and value, its tables (params, timing, ...) one level down
  return Object.entries(def).flatMap(([k, v]) => (v !== null && typeof v === "object" && !Array.isArray(v))
    ? definitionRows(v, `${prefix}${k}.`)
    : [el("tr", {}, el("td", {}, prefix + k), el("td", { class: "value" },
      typeof v === "string" ? v : JSON.stringify(v)))]);
}

function motionLegend(task) {
  // the shaded window's legend entry (a shape has none of its own)
  return { x: [null], y: [null], name: `the motion [${task.preparation_s}, ${task.preparation_s + task.duration_s}] s`,
    mode: "markers", type: "scatter", marker: { symbol: "square", size: 12, color: "#e6e6e6" }, hoverinfo: "skip" };
}

function motionShapes(task, y0 = 0, y1 = 1) {
  // the motion's window [P, P + T], shaded as the matplotlib figures do
  return [{ type: "rect", xref: "x", yref: "paper", x0: task.preparation_s, x1: task.preparation_s + task.duration_s,
    y0, y1, fillcolor: "#e6e6e6", line: { width: 0 }, layer: "below" }];
}

function drawConvergence(c) {
  const idx = c.objective.map((_, i) => i + 1);
  const pick = (test) => ({ x: idx.filter((_, i) => test(i)), y: c.objective.filter((_, i) => test(i)) });
  const traces = [
    Object.assign(pick((i) => c.success[i]), { name: "success", mode: "markers", type: "scatter",
      marker: { color: "#2e7d32", size: 5 } }),
    Object.assign(pick((i) => !c.success[i] && !c.fell[i]), { name: "balance kept, not a success", mode: "markers",
      type: "scatter", marker: { color: "#999", size: 4 } }),
    Object.assign(pick((i) => c.fell[i]), { name: "lost balance", mode: "markers", type: "scatter",
      marker: { color: "#c62828", symbol: "x", size: 5 } }),
    { x: idx, y: c.best_so_far, name: "best so far", mode: "lines", type: "scatter", line: { color: "#000" } },
  ];
  const shapes = [];
  if (c.threshold) {
    shapes.push({ type: "line", xref: "paper", x0: 0, x1: 1, y0: c.threshold, y1: c.threshold,
      line: { color: "#2e7d32", dash: "dash" } });
    traces.push({ x: [null], y: [null], name: `stop threshold ${c.threshold}`, mode: "lines", type: "scatter",
      line: { color: "#2e7d32", dash: "dash" } });
  }
  for (const r of c.restarts) {
    shapes.push({ type: "line", yref: "paper", x0: r - 0.5, x1: r - 0.5, y0: 0, y1: 1,
      line: { color: "#6a1b9a", dash: "dot" } });
  }
  if (c.restarts.length) {
    traces.push({ x: [null], y: [null], name: "restart", mode: "lines", type: "scatter",
      line: { color: "#6a1b9a", dash: "dot" } });
  }
  Plotly.react("convergence", traces, layout({ shapes, xaxis: Object.assign({ title: { text: "evaluation" } }, AXIS),
    yaxis: Object.assign({ title: { text: "objective" }, type: "log" }, AXIS) }), PLOT_CONFIG);
}

function drawCurves(page) {
  const z = page.zero_cmrt, traces = [
    { x: z.time_s, y: z.displacement_cm, name: "zero CMRT (no anticipation)", mode: "lines", type: "scatter",
      line: { color: "#888" } }];
  if (page.best_cmrt) {
    const b = page.best_cmrt;
    traces.push({ x: b.time_s, y: b.displacement_cm, name: "best CMRT", mode: "lines", type: "scatter",
      line: { color: "#1565c0", width: 2 } });
    traces.push({ x: b.knot_times_s, y: b.knot_values_cm, name: "knots", mode: "markers", type: "scatter",
      marker: { color: "#1565c0", size: 8 } });
    if (b.cross_displacement_cm) {  // a CMRT in x and y: its displacement across the task's axis
      traces.push({ x: b.time_s, y: b.cross_displacement_cm, name: "best CMRT, across", mode: "lines",
        type: "scatter", line: { color: "#2e7d32", width: 2, dash: "dash" } });
      traces.push({ x: b.knot_times_s, y: b.cross_knot_values_cm, name: "knots, across", mode: "markers",
        type: "scatter", marker: { color: "#2e7d32", size: 7, symbol: "square" } });
    }
  }
  traces.push(motionLegend(page.task));
  Plotly.react("cmrt", traces, layout({ shapes: motionShapes(page.task),
    xaxis: Object.assign({ title: { text: "time (s)" }, range: [0, page.task.clip_s] }, AXIS),
    yaxis: Object.assign({ title: { text: "d(t) (cm)" } }, AXIS) }), PLOT_CONFIG);
}

function drawTraces(t) {
  const colors = ["#888", "#1565c0"], traces = [], shapes = motionShapes(t.task);
  t.clips.forEach((c, i) => {
    traces.push({ x: c.time_s, y: c.cop_error_cm, name: `${c.label}: ${num(c.objective)} (${c.verdict})`,
      mode: "lines", type: "scatter", line: { color: colors[i], width: 1.4 } });
    if (c.cross_cop_error_cm) {  // a CMRT in x and y: the CoP error across the task's axis too
      traces.push({ x: c.time_s, y: c.cross_cop_error_cm, name: `${c.label}, across (${c.cross_axis})`,
        mode: "lines", type: "scatter", line: { color: colors[i], width: 1.0, dash: "dot" } });
    }
    if (c.fall_time_s !== null) {
      shapes.push({ type: "line", yref: "paper", x0: c.fall_time_s, x1: c.fall_time_s, y0: 0, y1: 1,
        line: { color: "#c62828", dash: "dot" } });
    }
  });
  const edge = t.clips[1], sideways = edge.axis === "y";  // a 3D leg lift: its sideways CoP error and support
  traces.push({ x: edge.time_s, y: edge.support_lo_cm, name: sideways ? "support edges (the feet's sides)"
    : "support edges (heel, toe)", mode: "lines",
    type: "scatter", line: { color: "#000", dash: "dash", width: 0.8 } });
  traces.push({ x: edge.time_s, y: edge.support_hi_cm, showlegend: false, mode: "lines", type: "scatter",
    line: { color: "#000", dash: "dash", width: 0.8 } });
  traces.push(motionLegend(t.task));
  Plotly.react("cop", traces, layout({ shapes, xaxis: Object.assign({ title: { text: "time (s)" } }, AXIS),
    yaxis: Object.assign({ title: { text: sideways ? "sideways CoP error p - s, y (cm)"
      : edge.axis === "x" ? "forward CoP error p - s, x (cm)" : "CoP error p - s (cm)" } },
      AXIS) }), PLOT_CONFIG);
  const head = el("tr", {}, el("th", {}, "figure"), ...t.clips.map((c) => el("th", {}, c.label)), el("th", {}, "limit"));
  const rows = t.plausibility_fields.map((f) => el("tr", {}, el("td", {}, f.label),
    ...t.clips.map((c) => el("td", { class: "num" }, num(c.plausibility[f.key]))),
    el("td", { class: "num" }, f.limit === null ? "-" : String(f.limit))));
  document.getElementById("plausibility").replaceChildren(head, ...rows);
}

async function loadTraces(id) {
  const note = document.getElementById("traces-note");
  try {
    drawTraces(await getJSON(`/api/runs/${id}/traces`));
    note.textContent = "drag to zoom, double-click to reset; each trace ends where balance was lost";
  } catch (err) {
    note.textContent = err.message;
  }
}

function renderClip(id) {
  const note = document.getElementById("clip-note"), video = document.getElementById("clip");
  note.textContent = "rendering (the first time takes a while) ...";
  fetch(`/clips/run${id}.mp4`).then(async (response) => {
    if (!response.ok) {
      const page = new DOMParser().parseFromString(await response.text(), "text/html");
      const message = page.getElementById("message");
      throw new Error(message ? message.textContent : response.statusText);
    }
    video.src = URL.createObjectURL(await response.blob());
    video.hidden = false;
    note.textContent = "";
  }).catch((err) => { note.textContent = `cannot show the clip: ${err.message}`; note.className = "error"; });
}

async function refreshRun(id, tracesLoaded) {
  const page = await getJSON(`/api/runs/${id}`);
  const r = page.run;
  document.title = `CMRT dashboard: run ${id}`;
  document.getElementById("title").textContent = `Run ${id}: ${page.task.label}`;
  const summary = document.getElementById("summary");
  summary.replaceChildren(statusCell(r), `: ${r.search}. ${r.restarts} restarts, reference ${r.reference}, ` +
    `seed ${r.seed}. Best objective ${num(r.best_objective)} `,
  verdictCell(r.best_success, r.best_fell), `; no CMRT ${num(r.baseline_objective)} `,
  verdictCell(r.baseline_success, r.baseline_fell), `; improvement ${num(r.improvement_over_zero)}; robustness: ` +
    (r.robustness ? `${robustnessText(r.robustness)} of its perturbed validation clips succeed` : "-"));
  drawConvergence(page.convergence);
  drawCurves(page);
  document.getElementById("store").textContent = page.store;
  document.getElementById("task").replaceChildren(...definitionRows(page.task_definition));
  document.getElementById("details").textContent = JSON.stringify(page.details, null, 2);
  const active = r.status === "queued" || r.status === "running";
  if (!tracesLoaded && !active && page.best_cmrt) loadTraces(id);
  if (active) {
    document.getElementById("traces-note").textContent = "shown once the run has finished";
    setTimeout(() => refreshRun(id, false), POLL_MS);
  }
  document.getElementById("render").disabled = !page.best_cmrt;
}

function runPage() {
  const id = runId();
  document.getElementById("render").addEventListener("click", () => renderClip(id));
  refreshRun(id, false).catch((err) => {
    document.getElementById("summary").textContent = err.message;
  });
}

// --- several runs ----------------------------------------------------------------------------------
async function comparePage() {
  const ids = new URLSearchParams(window.location.search).get("runs") || "";
  const note = document.getElementById("note");
  try {
    const data = await getJSON(`/api/compare?runs=${encodeURIComponent(ids)}`);
    const traces = [];
    data.runs.forEach((r, i) => {
      if (!r.curve) return;
      traces.push({ x: r.curve.time_s, y: r.curve.displacement_cm, name: `${r.label}: ${num(r.best_objective)}`,
        mode: "lines", type: "scatter", line: { color: `hsl(${(i * 67) % 360},70%,40%)`, width: 2 } });
    });
    data.interpolated.forEach((m) => {
      traces.push({ x: m.curve.time_s, y: m.curve.displacement_cm, name: `${m.label}: ${num(m.objective)}`,
        mode: "lines", type: "scatter", line: { dash: "dash", width: 1.5 } });
    });
    Plotly.react("curves", traces, layout({ xaxis: Object.assign({ title: { text: "time (s)" } }, AXIS),
      yaxis: Object.assign({ title: { text: "d(t) (cm)" } }, AXIS) }), PLOT_CONFIG);
    const head = el("tr", {}, ...["CMRT", "speed", "status", "best objective", "verdict", "no-CMRT objective",
      "improvement", "evaluations"].map((h) => el("th", {}, h)));
    const rows = data.runs.map((r) => el("tr", {}, el("td", {}, el("a", { href: `/runs/${r.id}` }, r.label)),
      el("td", { class: "num" }, r.speed === null ? "-" : String(r.speed)), el("td", {}, r.status),
      el("td", { class: "num" }, num(r.best_objective)), el("td", {}, verdictCell(r.best_success, r.best_fell)),
      el("td", { class: "num" }, num(r.baseline_objective)), el("td", { class: "num" }, num(r.improvement_over_zero)),
      el("td", { class: "num" }, String(r.evaluations))));
    const between = data.interpolated.map((m) => el("tr", {}, el("td", {}, m.label),
      el("td", { class: "num" }, String(m.speed)), el("td", {}, "interpolated"), el("td", { class: "num" }, num(m.objective)),
      el("td", {}, verdictCell(m.success, m.verdict === "lost balance")), el("td", {}, "-"), el("td", {}, "-"),
      el("td", {}, "-")));
    document.getElementById("objectives").replaceChildren(head, ...rows, ...between);
    note.textContent = data.interpolated.length
      ? "dashed: members halfway between neighbouring speeds, their CMRTs blended (Anticipatory Balance Control, section 4.2) and simulated"
      : "";
  } catch (err) {
    note.textContent = err.message;
    note.className = "error";
  }
}

const PAGES = { runs: runsPage, run: runPage, compare: comparePage };
(PAGES[document.body.dataset.page] || (() => {}))();

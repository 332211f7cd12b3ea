// Plot builders shared by the study page: pure functions from trials to plotly traces/layouts.
// They never fetch and never touch the DOM, so the page decides when to draw.

import { PARAMETERS, fmt, measuredValue, parametersIn, responseHtml, unitOf, withUnit } from "./api.js";

// Above this many points SVG gets slow; WebGL (scattergl) draws 10,000 points in milliseconds.
const WEBGL_ABOVE = 1500;

const COLORSCALE = "Viridis"; // perceptually uniform and colour-blind safe
const INK = "#1b1f24";
const GRID = "#e3e6ea";
const MEDIAN = "#d55e00"; // Okabe-Ito vermillion
const TARGET = "#0072b2"; // Okabe-Ito blue
const STRIP_TOP = 0.93; // top of Fig. 5's failed-runs strip, in the figure's fraction

export function baseLayout(extra = {}) {
  return {
    font: { family: "system-ui, -apple-system, Segoe UI, Roboto, Arial, sans-serif", size: 13, color: INK },
    paper_bgcolor: "#ffffff",
    plot_bgcolor: "#ffffff",
    margin: { l: 64, r: 24, t: 28, b: 56 },
    hoverlabel: { bgcolor: "#ffffff", bordercolor: INK, font: { color: INK } },
    legend: { orientation: "h", x: 0, y: 1.02, yanchor: "bottom" },
    ...extra,
  };
}

function axis(title, extra = {}) {
  return { title: { text: title }, gridcolor: GRID, zeroline: false, linecolor: "#8c959f", ticks: "outside", ...extra };
}

export const CONFIG = { displaylogo: false, responsive: true, modeBarButtonsToRemove: ["select2d", "lasso2d"] };

// Small deterministic horizontal spread so points of one generation do not sit on one vertical.
function jitter(trial) {
  const n = Number(trial.individual ?? 0) * 2654435761 + Number(trial.replicate ?? 0) * 40503;
  return ((n % 1000) / 1000 - 0.5) * 0.5;
}

function median(values) {
  const v = values.filter((x) => Number.isFinite(x)).sort((a, b) => a - b);
  if (!v.length) return null;
  const mid = Math.floor(v.length / 2);
  return v.length % 2 ? v[mid] : (v[mid - 1] + v[mid]) / 2;
}

function byGeneration(trials, value) {
  const groups = new Map();
  for (const t of trials) {
    const x = value(t);
    if (!Number.isFinite(x)) continue;
    if (!groups.has(t.generation)) groups.set(t.generation, []);
    groups.get(t.generation).push(x);
  }
  const generations = [...groups.keys()].sort((a, b) => a - b);
  return { x: generations, y: generations.map((g) => median(groups.get(g))), groups };
}

// customdata[5] holds the trial's responses as text ("N<sub>t</sub> = 3 items"), one line each.
// customdata[8] the item-wall parameters the trial carries, one line each ("" without them).
// customdata[9] the run's own T and cost and the whole protocol's (timesHtml).
const HOVER =
  "<b>%{customdata[0]}</b><br>generation %{customdata[6]}<br>" +
  "E = %{customdata[1]:.3s}Pa<br>ν = %{customdata[2]:.3f}<br>e = %{customdata[3]:.3f}<br>" +
  "μ = %{customdata[4]:.3f}<br>%{customdata[8]}%{customdata[5]}%{customdata[9]}<extra></extra>";

// The run's own T and cost, and the whole protocol's as the API prices it (TrialRead
// protocol_wall_time_s / protocol_cost, by the functions f2 is made of): they differ for a run
// that emptied the tray and stopped early. Each line starts with a break ("" before a result).
function timesHtml(t) {
  if (!Number.isFinite(t.wall_time_s)) return "";
  const run = `<br>this run: T = ${fmt(t.wall_time_s)} s, cost ${fmt(t.cost)}`;
  if (isFailed(t)) return `${run} (until it failed)`;
  return `${run}<br>whole protocol: T = ${fmt(t.protocol_wall_time_s)} s, cost ${fmt(t.protocol_cost)}`;
}

function wallLines(t, before = false) {
  return parametersIn(t.params).filter((p) => p.wall).map((p) => {
    const line = `${p.label} = ${fmt(t.params[p.key], 3)}${p.unit === "Pa" ? " Pa" : ""}`;
    return before ? `<br>${line}` : `${line}<br>`;
  }).join("");
}

function customdata(trials, responses) {
  return trials.map((t) => [
    t.id, t.params.E, t.params.nu, t.params.e, t.params.mu,
    responses.map((r) => `${responseHtml(r)} = ${withUnit(measuredValue(t, r), r, 4)}`).join("<br>"),
    t.generation, null, wallLines(t), timesHtml(t),
  ]);
}

// What the study's f1 is, in its unit (the API's f1_unit: one experiment's distance is in its
// response's unit; several are each divided by their tolerance, optimizer/objectives.py). With one
// experiment the API's f1_rule says which distance the search used (W1 of the replicates or the
// aggregate's), written with the responses' labels.
function f1Title(responses, f1unit, rule) {
  const unit = `(${unitOf({ unit: f1unit })})`;
  if (responses.length !== 1) return `f1 = max |simulated − target| / tolerance ${unit}`;
  if (!rule) return `f1 = |${responseHtml(responses[0])} − target| ${unit}`;
  return `f1 = ${rule.replaceAll(responses[0].name, responseHtml(responses[0])).replaceAll(" - ", " − ")} ${unit}`;
}

// What a failed run lacks, for captions and hover texts: "no N<sub>t</sub>".
export function noneHtml(responses) {
  return responses.length === 1 ? `no ${responseHtml(responses[0])}` : "no responses";
}

function yTop(trials, value = (t) => t.f1) {
  let top = 1;
  for (const t of trials) {
    const v = value(t);
    if (Number.isFinite(v)) top = Math.max(top, v);
  }
  return top;
}

// From a little below zero, so that values of 0 are not hidden under the axis line.
function fromZero(trials, value) {
  const top = yTop(trials, value);
  return [-0.06 * top, 1.06 * top];
}

// f2 is the cost or T of the whole protocol (optimizer/objectives.py): a run did less work once
// items left and stopped when the tray emptied, up to 6.4 times short of the protocol in
// benchmarks/paper-study-seed2023-protocol-cost (full_load_factor), and the API
// scales it by the function f2 is made of (TrialRead protocol_cost / protocol_wall_time_s; no
// second formula here). The points sit there, so the front's staircase runs through the f2 it
// was ranked on: with one replicate each point's x is its set's f2 on the study's own axis; with
// several the search ranked their mean, around which the set's runs sit. On the other axis the
// front is still the one ranked on the study's own, so points may sit below its staircase.
const X_AXES = {
  wall_time_s: { title: "computation time T of the whole protocol (s)", value: (t) => t.protocol_wall_time_s },
  cost: { title: "cost of the whole protocol (sphere-steps + contact-steps)", value: (t) => t.protocol_cost },
};

// Fig. 5's T panel shows what f2 ranks: the study's objective_time, of the whole protocol.
// ``summary``: its key in GET /generations, whose medians the panel draws.
const F2_PANEL = {
  wall: {
    title: "computation time T of the whole protocol (s)", value: (t) => t.protocol_wall_time_s,
    summary: "protocol_wall_time_s",
  },
  cost: { title: "cost of the whole protocol", value: (t) => t.protocol_cost, summary: "protocol_cost" },
};

// Runs that measured nothing (optimizer/outcomes.py): every status but "ok". Marker and colour
// per status, as in pareto.png (optimizer/report.py FAILURE_STYLE); a status not listed gets
// the fallback, so a new one is drawn without a change here.
const FAILURE_STYLE = {
  invalid: { symbol: "triangle-up", color: "#cc79a7" },
  unstable: { symbol: "x", color: "#d55e00" },
  timeout: { symbol: "square", color: "#e69f00" },
  error: { symbol: "diamond", color: "#000000" },
  cancelled: { symbol: "circle", color: "#999999" },
};
const FAILURE_FALLBACK = { symbol: "cross", color: "#56b4e9" };
const failureStyle = (status) => FAILURE_STYLE[status] || FAILURE_FALLBACK;

export function isFailed(trial) {
  return trial.state === "done" && trial.status !== null && trial.status !== undefined && trial.status !== "ok";
}

// The status that failed each individual: its first failed replicate's (as the optimiser reads
// it). Every trial of such an individual is drawn apart: its objectives are not measurements.
export function individualFailures(trials) {
  const failures = new Map();
  const sorted = trials.filter(isFailed).sort((a, b) => a.individual - b.individual || a.replicate - b.replicate);
  for (const t of sorted) if (!failures.has(t.individual)) failures.set(t.individual, t.status);
  return failures;
}

// "failed: 3 (unstable 2, timeout 1)", counted over runs like every other view.
export function failureCounts(trials) {
  const counts = new Map();
  for (const t of trials) if (isFailed(t)) counts.set(t.status, (counts.get(t.status) || 0) + 1);
  const order = [...Object.keys(FAILURE_STYLE), ...[...counts.keys()].filter((s) => !(s in FAILURE_STYLE)).sort()];
  const byStatus = order.filter((s) => counts.has(s)).map((s) => [s, counts.get(s)]);
  const total = byStatus.reduce((sum, [, n]) => sum + n, 0);
  const text = total ? `failed: ${total} (${byStatus.map(([s, n]) => `${s} ${n}`).join(", ")})` : "failed: 0";
  return { total, byStatus, text };
}

// customdata[5] holds what the run lacks ("no N<sub>t</sub>").
const FAILED_HOVER =
  "<b>%{customdata[0]}</b><br>generation %{customdata[6]}<br><b>%{customdata[7]}</b>: %{customdata[5]}, " +
  "not ranked<br>E = %{customdata[1]:.3s}Pa<br>ν = %{customdata[2]:.3f}<br>e = %{customdata[3]:.3f}<br>" +
  "μ = %{customdata[4]:.3f}%{customdata[8]}%{customdata[9]}<extra></extra>";

function failedCustomdata(trials, failures, responses) {
  return trials.map((t) => [
    t.id, t.params.E, t.params.nu, t.params.e, t.params.mu, noneHtml(responses), t.generation,
    t.status === "ok" ? `${failures.get(t.individual)} (another replicate)` : t.status, wallLines(t, true),
    timesHtml(t),
  ]);
}

// Trace 0: every measured trial, coloured by generation. Trace 1: the Pareto members again, as
// outlined diamonds on top, so the front stands out without relying on colour alone. Then one
// trace per failed status, in a strip of its own above the plot at the runs' real x: they sit
// apart from the measured points, never at a made-up f1.
export function paretoFigure(trials, xKey, maxGeneration, responses, f1unit, f1rule = "") {
  const x = X_AXES[xKey];
  const failures = individualFailures(trials);
  const failedOf = (t) => t.state === "done" && failures.get(t.individual);
  const shown = trials.filter((t) => !failedOf(t) && Number.isFinite(t.f1) && Number.isFinite(x.value(t)));
  const front = shown.filter((t) => t.pareto).sort((a, b) => x.value(a) - x.value(b));
  const type = shown.length > WEBGL_ABOVE ? "scattergl" : "scatter";
  const cmax = Math.max(1, maxGeneration);
  const all = {
    type, mode: "markers", name: "trials",
    x: shown.map(x.value), y: shown.map((t) => t.f1),
    customdata: customdata(shown, responses), hovertemplate: HOVER,
    marker: {
      size: 7, opacity: 0.8, color: shown.map((t) => t.generation), colorscale: COLORSCALE,
      // A thin dark rim keeps the light end of viridis visible on white.
      cmin: 0, cmax, line: { width: 0.6, color: "#3b3b3b" },
      colorbar: { title: { text: "generation" }, thickness: 12, len: 0.8, dtick: cmax > 12 ? undefined : 1 },
    },
  };
  const pareto = {
    type, mode: "lines+markers", name: "Pareto members",
    x: front.map(x.value), y: front.map((t) => t.f1),
    customdata: customdata(front, responses), hovertemplate: HOVER,
    line: { color: INK, width: 1, dash: "dot", shape: "hv" },
    marker: {
      symbol: "diamond", size: 13, color: front.map((t) => t.generation), colorscale: COLORSCALE,
      cmin: 0, cmax, line: { width: 2, color: INK },
    },
  };
  // The failed runs are drawn at the same x as the points, the protocol value: it is what
  // objectives.py put into their set's f2 before the penalty, and what pareto.png draws them at
  // (Evaluation.cost / wall_time_s). A failed run is never scaled (its full_load_factor is 1,
  // dem/scenarios/feeder.py), so that is its own T up to the failure: what it cost, not a
  // protocol it never ran; the hover says so. A replicate that ended ok of a failed set keeps
  // its scaled value.
  const failed = trials.filter((t) => failedOf(t) && Number.isFinite(x.value(t)));
  const counts = failureCounts(trials);
  const rows = counts.byStatus.map(([status]) => status);
  const strips = rows.map((status) => {
    const members = failed.filter((t) => failures.get(t.individual) === status);
    const style = failureStyle(status);
    return {
      type, mode: "markers", name: `${status} (not ranked)`,
      x: members.map(x.value), y: members.map(() => status), xaxis: "x", yaxis: "y2",
      customdata: failedCustomdata(members, failures, responses), hovertemplate: FAILED_HOVER,
      marker: { symbol: style.symbol, size: 9, color: style.color, line: { width: 1, color: style.color } },
    };
  });
  const layout = baseLayout({
    xaxis: axis(x.title),
    yaxis: axis(f1Title(responses, f1unit, f1rule), {
      range: fromZero(shown, (t) => t.f1), domain: rows.length ? [0, 0.78] : [0, 1],
    }),
    yaxis2: axis("", {
      domain: [0.84, 1], type: "category", categoryarray: rows, visible: rows.length > 0,
      showgrid: false, tickfont: { size: 11 },
    }),
    annotations: rows.length ? [{
      xref: "paper", yref: "paper", x: 0, y: 1.0, xanchor: "left", yanchor: "bottom", showarrow: false,
      text: `<b>${counts.text}</b> — ${noneHtml(responses)}, drawn apart, not ranked`, font: { size: 12, color: INK },
    }] : [],
    legend: { orientation: "h", x: 0, y: -0.22, yanchor: "top" },
    hovermode: "closest",
    uirevision: xKey,
  });
  // What is not drawn and is not a failure: runs still computing, extra replicates (the batch
  // after the search's generations) and search runs whose batch is not ranked yet.
  const drawn = new Set([...shown, ...failed]);
  const left = trials.filter((t) => !drawn.has(t));
  const unfinished = left.filter((t) => t.state !== "done").length;
  const outside = left.filter((t) => t.state === "done" && t.generation > maxGeneration).length;
  return {
    data: [all, pareto, ...strips], layout, counts,
    measured: shown.length, failed: failed.length,
    hidden: { unfinished, outside, unranked: left.length - unfinished - outside },
  };
}

// The paper's Fig. 5: each experiment's response ((a), and (b)... for several experiments, one
// above the other on the left) and T (the last letter, on the right) of every measured trial
// against generation, medians, targets; above the first panel, the failed runs of each
// generation stacked by status: a failed run measured nothing and its T is where it stopped,
// so no panel draws it. Axes: x/y the first response, x2/y2 T, x3/y3 the failed runs, x4/y4
// onwards the other responses.
//
// The T panel shows what f2 ranks (F2_PANEL): the study's objective_time ("cost" or "wall") of
// the whole protocol, not the run's own. The paper's T was the time of the full 65 s protocol,
// and a run's own is up to 6.4 times less (X_AXES): per run, a generation that
// found emptying sets looked faster for its outcome, not its parameters, which is what f2 was
// made to stop rewarding, and the panel would disagree with the Pareto plot beside it. The
// hover gives the run's own T too.
//
// Each generation's median and its W1 to the experiment (above a response's panel, and in its
// medians' hover) are the API's (GET /studies/{id}/generations, optimizer/generations.py),
// ``summaries`` its entries, so that the figure says what every other view of the generations
// says; none are drawn before they are read.
export function generationFigure(trials, responses, maxGeneration, summaries = [], objectiveTime = "cost") {
  const f2 = F2_PANEL[objectiveTime] || F2_PANEL.cost;
  const done = trials.filter((t) => t.state === "done" && !isFailed(t));
  const type = done.length > WEBGL_ABOVE ? "scattergl" : "scatter";
  const gens = done.map((t) => t.generation + jitter(t));
  const hover = customdata(done, responses);
  const points = (y, axisSuffix) => ({
    type, mode: "markers", name: "trials", showlegend: axisSuffix === "",
    x: gens, y, xaxis: "x" + axisSuffix, yaxis: "y" + axisSuffix,
    customdata: hover, hovertemplate: HOVER,
    marker: { size: 5, color: "#56b4e9", opacity: 0.7, line: { width: 0.5, color: "#0072b2" } },
  });
  // A response's medians carry each generation's W1 to the experiment's values: a median of noisy
  // single runs can sit on the target by chance, the distance says how like the experiment the
  // generation's runs are (GET /generations computes it, as summary.json's).
  const searched = summaries.filter((entry) => entry.generation <= maxGeneration);
  const w1Of = (name) => {
    const shown = searched.filter((entry) => entry.w1_to_experiment && name in entry.w1_to_experiment);
    return new Map(shown.map((entry) => [entry.generation, entry.w1_to_experiment[name]]));
  };
  // Where a generation of as many runs drawn from the experiment itself lands (the API's
  // as_experiment): its median's 5-95 % range, shaded behind each generation, and W1's 95th
  // percentile, below which the W1 label is bold: the generation behaves as the experiment does.
  const bandOf = (name) => new Map(
    searched.filter((entry) => entry.as_experiment?.[name]).map((entry) => [entry.generation, entry.as_experiment[name]]),
  );
  const distances = [];
  for (const [i, r] of responses.entries()) {
    const byGen = w1Of(r.name);
    if (byGen.size) distances.push({ axisSuffix: i === 0 ? "" : String(i + 3), byGen, bands: bandOf(r.name) });
  }
  // ``spreadOf``: an entry's spread of the panel's quantity (none for a generation without a
  // measured run, which the line then passes by).
  const medianTrace = (spreadOf, axisSuffix, name) => {
    const shown = searched.filter((entry) => spreadOf(entry));
    const x = shown.map((entry) => entry.generation);
    const y = shown.map((entry) => spreadOf(entry).median);
    const byGen = name === undefined ? null : w1Of(name);
    const w1 = byGen?.size ? x.map((g) => byGen.get(g) ?? null) : null;
    return {
      type: "scatter", mode: "lines+markers", name: "median per generation", showlegend: axisSuffix === "",
      x, y, xaxis: "x" + axisSuffix, yaxis: "y" + axisSuffix,
      line: { color: MEDIAN, width: 3 }, marker: { size: 8, color: MEDIAN },
      customdata: w1 ?? undefined,
      hovertemplate: "generation %{x}<br>median %{y:.3g}" +
        (w1 ? "<br>W1 to the experiment %{customdata:.2f}" : "") + "<extra></extra>",
    };
  };
  const suffixOf = (i) => (i === 0 ? "" : String(i + 3));
  const data = [];
  responses.forEach((r, i) => {
    const value = (t) => measuredValue(t, r);
    const spreadOf = (entry) => entry.responses?.[r.name];
    data.push(points(done.map(value), suffixOf(i)), medianTrace(spreadOf, suffixOf(i), r.name));
    if (i === 0) data.push(points(done.map(f2.value), "2"), medianTrace((entry) => entry[f2.summary], "2"));
  });
  if (distances.some((d) => d.bands.size)) {
    // The shaded bands are layout shapes, which have no legend entry: this empty trace is it.
    data.push({
      type: "scatter", mode: "markers", name: "median of as many runs drawn from the experiment, 5-95 %",
      x: [null], y: [null], hoverinfo: "skip",
      marker: { symbol: "square", size: 12, color: TARGET, opacity: 0.25 },
    });
  }
  const none = noneHtml(responses);
  const counts = failureCounts(trials);
  for (const [status] of counts.byStatus) {
    const perGeneration = new Map();
    for (const t of trials) {
      if (isFailed(t) && t.status === status) perGeneration.set(t.generation, (perGeneration.get(t.generation) || 0) + 1);
    }
    const generations = [...perGeneration.keys()].sort((a, b) => a - b);
    data.push({
      type: "bar", name: `${status} runs`, x: generations, y: generations.map((g) => perGeneration.get(g)),
      xaxis: "x3", yaxis: "y3", marker: { color: failureStyle(status).color }, width: 0.6,
      hovertemplate: `generation %{x}<br>%{y} ${status} run(s): ${none}<extra></extra>`,
    });
  }
  responses.forEach((r, i) => {
    if (!Number.isFinite(r.target)) return;
    data.push({
      type: "scatter", mode: "lines", name: `experimental target ${responseHtml(r)} = ${fmt(r.target)}`,
      x: [-0.5, Math.max(1, maxGeneration) + 0.5], y: [r.target, r.target],
      xaxis: "x" + suffixOf(i), yaxis: "y" + suffixOf(i),
      line: { color: TARGET, width: 2, dash: "dash" }, hoverinfo: "skip",
    });
  });
  const range = [-0.6, maxGeneration + 0.6];
  const genAxis = (title, domain) => axis(title, { dtick: maxGeneration > 15 ? undefined : 1, range, domain });
  // The response panels share the left column below the failed-runs strip, 0.06 apart.
  const gap = 0.06;
  const height = (0.74 - gap * (responses.length - 1)) / responses.length;
  const letter = (i) => String.fromCharCode(97 + i);
  const layout = baseLayout({
    xaxis2: genAxis("generation", [0.54, 1]),
    yaxis2: axis(`(${letter(responses.length)}) ${f2.title}`, {
      domain: [0, 1], range: fromZero(done, f2.value),
    }),
    xaxis3: genAxis("", [0, 0.46]),
    yaxis3: axis("failed runs", { domain: [0.8, STRIP_TOP], rangemode: "tozero", nticks: 3, title: { text: "failed<br>runs", font: { size: 11 } } }),
    barmode: "stack",
    // In paper coordinates at the strip's top: without failed runs the strip has no trace, so
    // plotly draws no x3/y3 subplot and a reference to its domain put the note among the points.
    annotations: [{
      xref: "paper", yref: "paper", x: 0, y: STRIP_TOP, xanchor: "left", yanchor: "bottom", showarrow: false,
      text: counts.total ? `${counts.text} — ${none}, ${responses.length === 1 ? "not in (a) or (b)" : "in no panel"}`
        : `no failed runs: every run measured ${responses.length === 1 ? responseHtml(responses[0]) : "every response"}`,
      font: { size: 12, color: INK },
    }],
    hovermode: "closest",
    margin: { l: 64, r: 24, t: 64, b: 56 },
    uirevision: "keep", // a zoom survives the next poll's redraw
  });
  responses.forEach((r, i) => {
    const top = 0.74 - i * (height + gap);
    const value = (t) => Math.max(measuredValue(t, r) ?? 0, Number.isFinite(r.target) ? r.target : 0);
    const last = i === responses.length - 1;
    layout["xaxis" + suffixOf(i)] = genAxis(last ? "generation" : "", [0, 0.46]);
    // Stacked panels are shorter: their titles drop "measured" to fit.
    const title = `(${letter(i)}) ${responses.length === 1 ? "measured " : ""}${responseHtml(r)} (${unitOf(r)})`;
    layout["yaxis" + suffixOf(i)] = axis(title, {
      domain: [Math.max(0, top - height), top], range: fromZero(done, value),
    });
    if (i > 0) {
      layout["xaxis" + suffixOf(i)].anchor = "y" + suffixOf(i);
      layout["yaxis" + suffixOf(i)].anchor = "x" + suffixOf(i);
    }
  });
  layout.shapes = [];
  for (const { axisSuffix, byGen, bands } of distances) {
    const at = (g, text) => ({
      xref: "x" + axisSuffix, yref: `y${axisSuffix} domain`, x: g, y: 1, yanchor: "bottom",
      showarrow: false, text, font: { size: 10, color: INK },
    });
    const label = (g) => {
      const w1 = byGen.get(g);
      if (!Number.isFinite(w1)) return "";
      return bands.has(g) && bands.get(g).alike ? `<b>${w1.toFixed(1)}</b>` : w1.toFixed(1);
    };
    const x = [...byGen.keys()].sort((a, b) => a - b);
    layout.annotations.push(at(x[0] - 0.55, "W1"), ...x.map((g) => at(g, label(g))));
    for (const [g, band] of bands) {
      layout.shapes.push({
        type: "rect", layer: "below", xref: "x" + axisSuffix, yref: "y" + axisSuffix, line: { width: 0 },
        x0: g - 0.4, x1: g + 0.4, y0: band.median_5, y1: band.median_95, fillcolor: TARGET, opacity: 0.12,
      });
    }
  }
  layout.xaxis3.showticklabels = false;
  layout.xaxis3.anchor = "y3";
  layout.xaxis2.anchor = "y2";
  layout.yaxis2.anchor = "x2";
  layout.yaxis3.anchor = "x3";
  return { data, layout, counts };
}

// Progress against simulations (GET /studies/{id}/progress): the hypervolume of what was
// measured (left axis, a fraction of the study's fixed reference box) and the best f1 and best
// validated f1 (right axis, in f1's unit), one point per completed batch.
export function progressFigure(progress, f1unit) {
  const unit = unitOf({ unit: f1unit });
  const inUnit = unit === "–" ? "" : ` ${unit}`;
  const points = progress.points || [];
  const sims = points.map((p) => p.simulations);
  const data = [
    {
      type: "scatter", mode: "lines+markers", name: "hypervolume", x: sims, y: points.map((p) => p.hypervolume),
      line: { color: TARGET, width: 3 }, marker: { size: 7, color: TARGET },
      hovertemplate: "%{x} simulations<br>hypervolume %{y:.3f}<extra></extra>",
    },
    {
      type: "scatter", mode: "lines+markers", name: "best f1", x: sims, y: points.map((p) => p.best_f1),
      yaxis: "y2", line: { color: MEDIAN, width: 2, shape: "hv" }, marker: { size: 6, color: MEDIAN },
      hovertemplate: `%{x} simulations<br>best f1 %{y:.3g}${inUnit}<extra></extra>`,
    },
    {
      type: "scatter", mode: "lines+markers", name: "best validated f1", x: sims,
      y: points.map((p) => p.best_validated_f1), yaxis: "y2",
      line: { color: "#009e73", width: 2, dash: "dot", shape: "hv" }, marker: { size: 8, symbol: "star", color: "#009e73" },
      hovertemplate: `%{x} simulations<br>best validated f1 %{y:.3g}${inUnit}<extra></extra>`,
    },
  ];
  const ref = progress.reference;
  const f1Top = Math.max(1, ...points.flatMap((p) => [p.best_f1, p.best_validated_f1]).filter(Number.isFinite));
  const layout = baseLayout({
    xaxis: axis("simulations", { rangemode: "tozero" }),
    yaxis: axis("hypervolume (fraction of the reference box)", { range: [0, 1.02] }),
    yaxis2: axis(`f1 (${unit})`, {
      overlaying: "y", side: "right", showgrid: false, tickmode: "auto", nticks: 6,
      range: [-0.02 * f1Top, 1.05 * f1Top],
    }),
    margin: { l: 64, r: 64, t: 28, b: 56 },
    hovermode: "x unified",
    uirevision: "keep",
  });
  const caption = ref
    ? `Reference point (fixed once the initial population is complete): f1 = ${fmt(ref.f1)}${inUnit}, ` +
      `f2 = ${fmt(ref.f2)} (1.1 × the initial population's largest).`
    : "No point yet: the hypervolume's reference is fixed when the initial population is complete.";
  return { data, layout, caption };
}

// One panel per searched parameter: values against generation with the median; fixed ones
// skipped. A large study gets a box per generation instead of its points: four panels of
// 10,000 coloured points cost seconds to draw, and the boxes show the narrowing just as well.
export function parameterFigure(trials, bounds, maxGeneration, responses, f1unit) {
  // An item parameter without bounds has the default ones; a wall one the study does not name
  // is no parameter of it.
  const free = PARAMETERS.filter((p) => (p.wall ? bounds[p.key] != null : true) && bounds[p.key]?.fixed == null);
  const all = trials.filter((t) => t.params && t.state !== "cancelled");
  const boxes = all.length > WEBGL_ABOVE;
  // Where the search went (all proposals, for the medians and boxes); the points are coloured by
  // f1 only where it is a measurement, failed individuals are grey crosses apart from the scale.
  const failures = individualFailures(trials);
  const failedOf = (t) => t.state === "done" && failures.has(t.individual);
  const proposed = all.filter((t) => !failedOf(t));
  // Coloured only where f1 is known: a queued, running or not yet ranked trial has none, and
  // colouring it would put it on the scale (as f1 0, and the scale at -0.5..0.5 when none has one).
  const done = proposed.filter((t) => Number.isFinite(t.f1));
  const unranked = proposed.filter((t) => !Number.isFinite(t.f1));
  const failed = all.filter(failedOf);
  const gens = done.map((t) => t.generation + jitter(t));
  const data = [];
  const layout = baseLayout({
    grid: { rows: Math.ceil(free.length / 2), columns: Math.min(2, free.length), pattern: "independent" },
    hovermode: "closest",
    margin: { l: 72, r: 24, t: 40, b: 56 },
    uirevision: "keep",
  });
  free.forEach((p, i) => {
    const suffix = i === 0 ? "" : String(i + 1);
    if (boxes) {
      data.push({
        type: "box", name: "trials (quartiles, 1.5 IQR whiskers)", showlegend: i === 0,
        x: all.map((t) => t.generation), y: all.map((t) => t.params[p.key]),
        xaxis: "x" + suffix, yaxis: "y" + suffix, boxpoints: false,
        fillcolor: "rgba(86, 180, 233, 0.35)", line: { color: "#0072b2", width: 1.2 },
      });
    } else {
      data.push({
        type: "scatter", mode: "markers", name: "trials", showlegend: i === 0,
        x: gens, y: done.map((t) => t.params[p.key]), xaxis: "x" + suffix, yaxis: "y" + suffix,
        customdata: customdata(done, responses), hovertemplate: HOVER,
        marker: { size: 6, color: done.map((t) => t.f1), colorscale: "Cividis", reversescale: true,
          cmin: 0, showscale: i === 0 && done.length > 0, line: { width: 0.6, color: "#3b3b3b" },
          colorbar: { title: { text: `f1 (${unitOf({ unit: f1unit })})` }, thickness: 12, len: 0.8 } },
      });
      data.push({
        type: "scatter", mode: "markers", name: "no f1 yet (queued, running or not ranked)", showlegend: i === 0,
        x: unranked.map((t) => t.generation + jitter(t)), y: unranked.map((t) => t.params[p.key]),
        xaxis: "x" + suffix, yaxis: "y" + suffix, customdata: customdata(unranked, responses), hovertemplate: HOVER,
        marker: { size: 6, symbol: "circle-open", color: "#8c959f", line: { width: 1 } },
      });
      data.push({
        type: "scatter", mode: "markers", name: `failed (${noneHtml(responses)})`, showlegend: i === 0,
        x: failed.map((t) => t.generation + jitter(t)), y: failed.map((t) => t.params[p.key]),
        xaxis: "x" + suffix, yaxis: "y" + suffix,
        customdata: failedCustomdata(failed, failures, responses), hovertemplate: FAILED_HOVER,
        marker: { size: 7, symbol: "x-thin", color: "#8c959f", line: { width: 1.5, color: "#8c959f" } },
      });
    }
    const m = byGeneration(all, (t) => t.params[p.key]);
    data.push({
      type: "scatter", mode: "lines+markers", name: "median per generation", showlegend: i === 0,
      x: m.x, y: m.y, xaxis: "x" + suffix, yaxis: "y" + suffix,
      line: { color: MEDIAN, width: 3 }, marker: { size: 7, color: MEDIAN },
      hovertemplate: `generation %{x}<br>median ${p.label} = %{y:.3g}<extra></extra>`,
    });
    const b = bounds[p.key] || {};
    // The search bounds with 4 % room, so points at a bound are not cut by the axis line.
    let range;
    if (Number.isFinite(b.low) && Number.isFinite(b.high)) {
      const [lo, hi] = p.log ? [Math.log10(b.low), Math.log10(b.high)] : [b.low, b.high];
      range = [lo - 0.04 * (hi - lo), hi + 0.04 * (hi - lo)];
    }
    layout["xaxis" + suffix] = axis("generation", { dtick: maxGeneration > 15 ? undefined : 1, range: [-0.6, maxGeneration + 0.6] });
    layout["yaxis" + suffix] = axis(p.title, { type: p.log ? "log" : "linear", range, exponentformat: "power" });
  });
  return { data, layout };
}

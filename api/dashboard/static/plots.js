// Plot builders shared by the study page: pure functions from trials to plotly traces/layouts.
// They never fetch and never touch the DOM, so the page decides when to draw.

import { PARAMETERS, fmt } from "./api.js";

// Above this many points SVG gets slow; WebGL (scattergl) draws 10,000 points in milliseconds.
const WEBGL_ABOVE = 1500;

const COLORSCALE = "Viridis"; // perceptually uniform and colour-blind safe
const INK = "#1b1f24";
const GRID = "#e3e6ea";
const MEDIAN = "#d55e00"; // Okabe-Ito vermillion
const TARGET = "#0072b2"; // Okabe-Ito blue

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
  return { x: generations, y: generations.map((g) => median(groups.get(g))) };
}

const HOVER =
  "<b>%{customdata[0]}</b><br>generation %{customdata[6]}<br>" +
  "E = %{customdata[1]:.3s}Pa<br>ν = %{customdata[2]:.3f}<br>e = %{customdata[3]:.3f}<br>" +
  "μ = %{customdata[4]:.3f}<br>N<sub>t</sub> = %{customdata[5]}<extra></extra>";

function customdata(trials) {
  return trials.map((t) => [
    t.id, t.params.E, t.params.nu, t.params.e, t.params.mu, t.n_remaining ?? "–", t.generation,
  ]);
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

const X_AXES = {
  wall_time_s: { title: "computation time T (s)", value: (t) => t.wall_time_s },
  cost: { title: "cost (sphere-steps + contact-steps)", value: (t) => t.cost },
};

// Trace 0: every finished trial, coloured by generation. Trace 1: the Pareto members again, as
// outlined diamonds on top, so the front stands out without relying on colour alone.
export function paretoFigure(trials, xKey, maxGeneration) {
  const x = X_AXES[xKey];
  const shown = trials.filter((t) => Number.isFinite(t.f1) && Number.isFinite(x.value(t)));
  const front = shown.filter((t) => t.pareto).sort((a, b) => x.value(a) - x.value(b));
  const type = shown.length > WEBGL_ABOVE ? "scattergl" : "scatter";
  const cmax = Math.max(1, maxGeneration);
  const all = {
    type, mode: "markers", name: "trials",
    x: shown.map(x.value), y: shown.map((t) => t.f1),
    customdata: customdata(shown), hovertemplate: HOVER,
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
    customdata: customdata(front), hovertemplate: HOVER,
    line: { color: INK, width: 1, dash: "dot", shape: "hv" },
    marker: {
      symbol: "diamond", size: 13, color: front.map((t) => t.generation), colorscale: COLORSCALE,
      cmin: 0, cmax, line: { width: 2, color: INK },
    },
  };
  const layout = baseLayout({
    xaxis: axis(x.title),
    yaxis: axis("f1 = |N<sub>t</sub> − target| (items)", { range: fromZero(shown, (t) => t.f1) }),
    hovermode: "closest",
    uirevision: xKey,
  });
  return { data: [all, pareto], layout, hidden: trials.length - shown.length };
}

// The paper's Fig. 5: N_t (a) and T (b) of every trial against generation, medians, target.
export function generationFigure(trials, target, maxGeneration) {
  const done = trials.filter((t) => t.state === "done");
  const type = done.length > WEBGL_ABOVE ? "scattergl" : "scatter";
  const gens = done.map((t) => t.generation + jitter(t));
  const points = (y, axisSuffix) => ({
    type, mode: "markers", name: "trials", showlegend: axisSuffix === "",
    x: gens, y, xaxis: "x" + axisSuffix, yaxis: "y" + axisSuffix,
    customdata: customdata(done), hovertemplate: HOVER,
    marker: { size: 5, color: "#56b4e9", opacity: 0.7, line: { width: 0.5, color: "#0072b2" } },
  });
  const medianTrace = (value, axisSuffix) => {
    const m = byGeneration(done, value);
    return {
      type: "scatter", mode: "lines+markers", name: "median per generation", showlegend: axisSuffix === "",
      x: m.x, y: m.y, xaxis: "x" + axisSuffix, yaxis: "y" + axisSuffix,
      line: { color: MEDIAN, width: 3 }, marker: { size: 8, color: MEDIAN },
      hovertemplate: "generation %{x}<br>median %{y:.3g}<extra></extra>",
    };
  };
  const data = [
    points(done.map((t) => t.n_remaining), ""),
    medianTrace((t) => t.n_remaining, ""),
    points(done.map((t) => t.wall_time_s), "2"),
    medianTrace((t) => t.wall_time_s, "2"),
  ];
  const shapes = [];
  if (Number.isFinite(target)) {
    data.push({
      type: "scatter", mode: "lines", name: `experimental target N<sub>t</sub> = ${fmt(target)}`,
      x: [-0.5, Math.max(1, maxGeneration) + 0.5], y: [target, target],
      line: { color: TARGET, width: 2, dash: "dash" }, hoverinfo: "skip",
    });
  }
  const genAxis = (title) => axis(title, { dtick: maxGeneration > 15 ? undefined : 1, range: [-0.6, maxGeneration + 0.6] });
  const layout = baseLayout({
    grid: { rows: 1, columns: 2, pattern: "independent" },
    xaxis: genAxis("generation"),
    yaxis: axis("(a) items remaining N<sub>t</sub> (items)", {
      range: fromZero(done, (t) => Math.max(t.n_remaining ?? 0, Number.isFinite(target) ? target : 0)),
    }),
    xaxis2: genAxis("generation"),
    yaxis2: axis("(b) computation time T (s)", { range: fromZero(done, (t) => t.wall_time_s) }),
    shapes,
    hovermode: "closest",
    margin: { l: 64, r: 24, t: 40, b: 56 },
    uirevision: "keep", // a zoom survives the next poll's redraw
  });
  return { data, layout };
}

// One panel per searched parameter: values against generation with the median; fixed ones
// skipped. A large study gets a box per generation instead of its points: four panels of
// 10,000 coloured points cost seconds to draw, and the boxes show the narrowing just as well.
export function parameterFigure(trials, bounds, maxGeneration) {
  const free = PARAMETERS.filter((p) => !bounds[p.key] || bounds[p.key].fixed == null);
  const done = trials.filter((t) => t.params && t.state !== "cancelled");
  const boxes = done.length > WEBGL_ABOVE;
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
        x: done.map((t) => t.generation), y: done.map((t) => t.params[p.key]),
        xaxis: "x" + suffix, yaxis: "y" + suffix, boxpoints: false,
        fillcolor: "rgba(86, 180, 233, 0.35)", line: { color: "#0072b2", width: 1.2 },
      });
    } else {
      data.push({
        type: "scatter", mode: "markers", name: "trials", showlegend: i === 0,
        x: gens, y: done.map((t) => t.params[p.key]), xaxis: "x" + suffix, yaxis: "y" + suffix,
        customdata: customdata(done), hovertemplate: HOVER,
        marker: { size: 6, color: done.map((t) => t.f1), colorscale: "Cividis", reversescale: true,
          cmin: 0, showscale: i === 0, line: { width: 0.6, color: "#3b3b3b" },
          colorbar: { title: { text: "f1 (items)" }, thickness: 12, len: 0.8 } },
      });
    }
    const m = byGeneration(done, (t) => t.params[p.key]);
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

// The trial page: parameters, seed, status and timings, every response the scenario declares
// with its unit; the discharge curve (items remaining against simulated time, from the result's
// discharge_times, when the scenario records one); and, when the trial kept snapshots, a replay
// in 3D (replay3d.js) beside a top view on a canvas, with the items retained at the end marked.

import {
  ApiError, api, apiKey, el, experimentResponses, fmt, fmtSeconds, fmtTime, measuredValue,
  parametersIn, plotlyReady, poll, responseHtml, responseText, showBanner, statusBadge, withUnit,
} from "./api.js";
import { CONFIG, baseLayout } from "./plots.js";
import { draw3d, motionText } from "./replay3d.js";

const section = document.getElementById("trial");
const trialId = section.dataset.trialId;
const studyId = section.dataset.studyId;
const trialPath = `/studies/${encodeURIComponent(studyId)}/trials/${encodeURIComponent(trialId)}`;

const RETAINED = "#e69f00"; // Okabe-Ito orange
const DISCHARGED = "#56b4e9"; // Okabe-Ito sky blue
const INK = "#1b1f24";

// A response's value as the facts show it: "31.2 deg"; a count of the run's items "3 of 30 items".
function responseValue(trial, response) {
  const value = measuredValue(trial, response);
  if (value === null) {
    return trial.status && trial.status !== "ok" ? `none: the run ended ${trial.status}, it measured nothing` : "–";
  }
  const total = trial.result?.n_items;
  return response.unit === "items" && total ? `${fmt(value, 4)} of ${total} items` : withUnit(value, response, 4);
}

function facts(trial, declared, experiments, f1unit) {
  const r = trial.result || {};
  const rows = [
    ...parametersIn(trial.params).map((p) => [p.title, fmt(trial.params?.[p.key], 4)]),
    ["seed", trial.seed],
    ["generation · individual · replicate", `${trial.generation} · ${trial.individual} · ${trial.replicate}`],
    ["state / simulation status", `${trial.state} / ${trial.status ?? "–"}`],
    ...declared.map((response) => [responseText(response), responseValue(trial, response)]),
    [experiments.length === 1 ? `f1 = |${responseText(experiments[0])} − target|` : "f1 = max |simulated − target| / tolerance",
      trial.f1 !== null ? withUnit(trial.f1, { unit: f1unit }) : "–"],
    ["Pareto member", trial.pareto ? "yes" : "no"],
    ["wall time T", fmtSeconds(trial.wall_time_s)],
    ["cost", fmt(trial.cost)],
    ["simulated time", r.sim_time !== undefined ? `${fmt(r.sim_time)} s` : "–"],
    ["time step", trial.dt ? `${fmt(trial.dt)} s` : "–"],
    ["steps", r.steps !== undefined ? r.steps.toLocaleString() : "–"],
    ["tray emptied at", r.emptied_at != null ? `${fmt(r.emptied_at)} s` : "did not empty"],
    ["worker · attempts", `${trial.worker ?? "–"} · ${trial.attempts}`],
    ["created", fmtTime(trial.created_at)],
    ["started", fmtTime(trial.started_at)],
    ["finished", fmtTime(trial.finished_at)],
  ];
  document.getElementById("trial-facts").replaceChildren(
    ...rows.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", { text: String(v) })]));
}

// Items remaining: a step down at every discharge time, flat to the end of the run. The target is
// drawn when the study's one experiment is on that count (its response is counted in items).
async function dischargePlot(trial, experiments) {
  const r = trial.result;
  const box = document.getElementById("discharge-plot");
  // A scenario that records no discharge curve (a heap) has no card for it.
  box.closest(".card").hidden = trial.state === "done" && !r?.discharge_times?.length;
  if (!r || !r.discharge_times?.length) {
    box.replaceChildren(el("p", { class: "muted", text: "No result yet: the curve appears when the simulation has finished." }));
    return;
  }
  const times = r.discharge_times.filter((t) => t !== null).sort((a, b) => a - b);
  const n = r.discharge_times.length;
  const end = Math.max(r.sim_time || 0, times.at(-1) || 0);
  const x = [0, ...times, end];
  const y = [n, ...times.map((_, i) => n - i - 1), n - times.length];
  const data = [{
    type: "scatter", mode: "lines", name: "simulation", x, y, line: { shape: "hv", color: "#0072b2", width: 2.5 },
    hovertemplate: "t = %{x:.2f} s<br>%{y} items in the tray<extra></extra>",
  }];
  const counted = experiments.length === 1 && experiments[0].unit === "items" ? experiments[0] : null;
  const target = counted ? counted.target : NaN;
  if (Number.isFinite(target)) {
    data.push({
      type: "scatter", mode: "lines", name: `experimental target ${responseHtml(counted)} = ${fmt(target)}`,
      x: [0, end], y: [target, target], line: { color: "#d55e00", dash: "dash", width: 2 }, hoverinfo: "skip",
    });
  }
  const layout = baseLayout({
    xaxis: { title: { text: "simulated time t (s)" }, gridcolor: "#e3e6ea", range: [0, end], zeroline: false },
    yaxis: { title: { text: "items in the tray (items)" }, gridcolor: "#e3e6ea", range: [0, n + 0.5], zeroline: false },
  });
  await plotlyReady();
  if (!box.data) box.replaceChildren(); // drop the "no result yet" note before the first draw
  Plotly.react(box, data, layout, CONFIG);
}

// ---- replay ---------------------------------------------------------------------------------

function rotate(q, p) {
  const [w, x, y, z] = q;
  const [px, py, pz] = p;
  // v' = v + 2w (q x v) + 2 q x (q x v), with q the vector part
  const cx = y * pz - z * py, cy = z * px - x * pz, cz = x * py - y * px;
  const dx = y * cz - z * cy, dy = z * cx - x * cz;
  return [px + 2 * (w * cx + dx), py + 2 * (w * cy + dy)];
}

// Andrew's monotone chain: the top-view outline of a body is the convex hull of its projection.
function hull2d(points) {
  const p = points.slice().sort((a, b) => a[0] - b[0] || a[1] - b[1]);
  if (p.length < 3) return p;
  const cross = (o, a, b) => (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]);
  const lower = [];
  for (const q of p) {
    while (lower.length >= 2 && cross(lower.at(-2), lower.at(-1), q) <= 0) lower.pop();
    lower.push(q);
  }
  const upper = [];
  for (const q of p.reverse()) {
    while (upper.length >= 2 && cross(upper.at(-2), upper.at(-1), q) <= 0) upper.pop();
    upper.push(q);
  }
  return lower.slice(0, -1).concat(upper.slice(0, -1));
}

class Replay {
  constructor(doc, canvas) {
    this.doc = doc;
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    const xs = doc.tray.vertices.map((v) => v[0]);
    const ys = doc.tray.vertices.map((v) => v[1]);
    // Room beyond the outlet end so that items leaving the tray stay visible for a moment.
    this.box = { x0: Math.min(...xs) - 0.03, x1: Math.max(...xs) + 0.12, y0: Math.min(...ys) - 0.03, y1: Math.max(...ys) + 0.03 };
    const w = this.box.x1 - this.box.x0, h = this.box.y1 - this.box.y0;
    canvas.height = Math.round(canvas.width * (h / w)) + 40;
    this.scale = canvas.width / w;
  }

  px(x, y) {
    return [(x - this.box.x0) * this.scale, 40 + (this.box.y1 - y) * this.scale];
  }

  draw(index) {
    const { ctx, doc } = this;
    const f = doc.frames;
    ctx.clearRect(0, 0, this.canvas.width, this.canvas.height);
    ctx.fillStyle = "#fbfbf8";
    ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
    ctx.lineWidth = 0.6;
    ctx.fillStyle = "#e4e4e0";
    ctx.strokeStyle = "#a0a09a";
    for (const face of doc.tray.faces) {
      ctx.beginPath();
      face.forEach((vi, k) => {
        const [x, y] = this.px(doc.tray.vertices[vi][0], doc.tray.vertices[vi][1]);
        if (k === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
      });
      ctx.closePath();
      ctx.fill();
      ctx.stroke();
    }
    const pos = f.pos[index], quat = f.quat[index], state = f.state[index];
    // Lowest first, so the top view shows what a camera above the tray would see.
    const order = pos.map((_, i) => i).sort((a, b) => pos[a][2] - pos[b][2]);
    let inTray = 0;
    for (const i of order) {
      if (state[i] !== 1) continue;
      inTray += 1;
      const outline = hull2d(doc.items[i].hull.map((p) => {
        const [rx, ry] = rotate(quat[i], p);
        return this.px(pos[i][0] + rx, pos[i][1] + ry);
      }));
      const retained = doc.retained[i];
      ctx.beginPath();
      outline.forEach(([x, y], k) => (k === 0 ? ctx.moveTo(x, y) : ctx.lineTo(x, y)));
      ctx.closePath();
      ctx.fillStyle = retained ? RETAINED : DISCHARGED;
      ctx.globalAlpha = 0.9;
      ctx.fill();
      ctx.globalAlpha = 1;
      ctx.lineWidth = retained ? 2.5 : 1;
      ctx.strokeStyle = INK;
      ctx.stroke();
    }
    this.legend(f.t[index], inTray);
  }

  legend(t, inTray) {
    const { ctx } = this;
    ctx.fillStyle = INK;
    ctx.font = "600 16px system-ui, sans-serif";
    ctx.fillText(`t = ${t.toFixed(2)} s    items in the tray: ${inTray}`, 12, 26);
    let x = this.canvas.width - 470;
    for (const [colour, label, width] of [[RETAINED, "retained at the end", 2.5], [DISCHARGED, "discharged", 1]]) {
      ctx.fillStyle = colour;
      ctx.fillRect(x, 12, 18, 18);
      ctx.lineWidth = width;
      ctx.strokeStyle = INK;
      ctx.strokeRect(x, 12, 18, 18);
      ctx.fillStyle = INK;
      ctx.font = "15px system-ui, sans-serif";
      ctx.fillText(label, x + 26, 26);
      x += 190;
    }
    // A 100 mm scale bar, bottom left.
    const [x0, y0] = [14, this.canvas.height - 14];
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(x0, y0);
    ctx.lineTo(x0 + 0.1 * this.scale, y0);
    ctx.stroke();
    ctx.font = "13px system-ui, sans-serif";
    ctx.fillText("100 mm", x0, y0 - 6);
    ctx.fillText("outlet →", this.canvas.width - 80, this.canvas.height - 14);
  }
}

async function replay() {
  const caption = document.getElementById("replay-caption");
  let doc;
  try {
    doc = await api(`${trialPath}/replay`);
  } catch (error) {
    if (error instanceof ApiError && error.status === 404) {
      caption.textContent = "This trial kept no snapshots, so there is nothing to replay. " +
        "Runs with snapshots on keep them in <DEMCAL_DATA_DIR>/snapshots/<trial id>/.";
      document.getElementById("replay-wrap").hidden = true;
      return;
    }
    throw error;
  }
  const player = new Replay(doc, document.getElementById("replay"));
  const box3d = document.getElementById("replay-3d");
  const slider = document.getElementById("replay-frame");
  const button = document.getElementById("replay-play");
  const label = document.getElementById("replay-time");
  const count = doc.frames.t.length;
  slider.max = String(count - 1);
  slider.value = String(count - 1);
  slider.disabled = false;
  button.disabled = false;
  document.getElementById("replay-motion").textContent = motionText(doc);
  await plotlyReady();
  const colours = { retained: RETAINED, discharged: DISCHARGED };
  const show = (i) => {
    player.draw(i);
    box3d.dataset.frame = String(i);
    draw3d(box3d, doc, i, colours);
    label.textContent = `frame ${i + 1} of ${count} (t = ${doc.frames.t[i].toFixed(2)} s)`;
  };
  show(count - 1);
  let playing = null;
  slider.addEventListener("input", () => show(Number(slider.value)));
  button.addEventListener("click", () => {
    if (playing) {
      clearInterval(playing);
      playing = null;
      button.textContent = "Play";
      return;
    }
    if (Number(slider.value) >= count - 1) slider.value = "0";
    button.textContent = "Pause";
    playing = setInterval(() => {
      const next = Number(slider.value) + 1;
      if (next >= count) {
        clearInterval(playing);
        playing = null;
        button.textContent = "Play";
        return;
      }
      slider.value = String(next);
      show(next);
    }, 50);
  });
  section.dataset.replayFrames = String(count);
}

function showTrial(trial, study) {
  document.getElementById("trial-status").replaceWith(
    Object.assign(statusBadge(trial.status || trial.state), { id: "trial-status" }));
  const message = document.getElementById("trial-message");
  message.textContent = trial.message || "";
  message.hidden = !trial.message;
  const experiments = experimentResponses(study);
  facts(trial, study.responses || [], experiments, study.f1_unit);
  return dischargePlot(trial, experiments);
}

// A trial that is still queued or running is re-read every few seconds until it has a result;
// the replay is loaded once, when it has finished.
async function start() {
  if (!studyId) {
    showBanner(`${trialId} is not a trial id (expected <study>-iNNNNN-rNN).`);
    return;
  }
  document.getElementById("study-link").href = `/studies/${encodeURIComponent(studyId)}`;
  document.getElementById("study-link").textContent = `← study ${studyId}`;
  if (!apiKey()) {
    showBanner("Paste an API key (from `demcal apikey create`) in the box above to see this trial.", "warn");
    return;
  }
  const study = await api(`/studies/${encodeURIComponent(studyId)}`);
  poll(async () => {
    const trial = await api(trialPath);
    await showTrial(trial, study);
    const finished = trial.state === "done" || trial.state === "cancelled";
    if (finished) await replay();
    section.dataset.loaded = "1";
    return !finished;
  }, 3000);
}

start().catch((error) => {
  if (!(error instanceof ApiError)) console.error(error);
  showBanner(error.message);
});

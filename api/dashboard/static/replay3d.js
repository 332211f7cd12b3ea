// The trial's replay in 3D, on plotly's WebGL traces (mesh3d, no other library): the tray as its
// triangles, tilted as it was and moved by its recorded displacement; each item still in the tray
// as its convex hull placed by its pose, in the top view's colours; the tray's vibration as an
// arrow. Pure functions from the replay document (GET .../replay) to traces, and one draw call;
// the page owns the slider and the play button.

import { CONFIG, baseLayout } from "./plots.js";

const TRAY = "#9aa0a6";
const ARROW = "#d55e00"; // Okabe-Ito vermillion
const ARROW_LENGTH = 0.12; // m, drawn above the back of the tray

// v' = v + 2w (q x v) + 2 q x (q x v), with q = (w, x, y, z) scalar first, body to world.
function rotate(q, p) {
  const [w, x, y, z] = q;
  const [px, py, pz] = p;
  const cx = y * pz - z * py, cy = z * px - x * pz, cz = x * py - y * px;
  const dx = y * cz - z * cy, dy = z * cx - x * cz, dz = x * cy - y * cx;
  return [px + 2 * (w * cx + dx), py + 2 * (w * cy + dy), pz + 2 * (w * cz + dz)];
}

// The view box: the tray with room above it and beyond the outlet, the same for every frame so
// that the scene does not rescale while it plays.
export function viewBox(doc) {
  const v = doc.tray.vertices;
  const lo = [0, 1, 2].map((a) => Math.min(...v.map((p) => p[a])));
  const hi = [0, 1, 2].map((a) => Math.max(...v.map((p) => p[a])));
  return { lo: [lo[0] - 0.03, lo[1] - 0.03, lo[2] - 0.03], hi: [hi[0] + 0.12, hi[1] + 0.03, hi[2] + 0.12] };
}

export function trayTrace(doc, index) {
  const offset = doc.frames.tray_offset?.[index] ?? [0, 0, 0];
  const v = doc.tray.vertices;
  return {
    type: "mesh3d", name: "tray", hoverinfo: "skip", color: TRAY, opacity: 0.3, flatshading: true,
    x: v.map((p) => p[0] + offset[0]), y: v.map((p) => p[1] + offset[1]), z: v.map((p) => p[2] + offset[2]),
    i: doc.tray.faces.map((f) => f[0]), j: doc.tray.faces.map((f) => f[1]), k: doc.tray.faces.map((f) => f[2]),
  };
}

// Every item in the tray at frame ``index`` in one mesh (one WebGL draw), a face colour per item.
export function itemsTrace(doc, index, colours) {
  const f = doc.frames;
  const x = [], y = [], z = [], i = [], j = [], k = [], facecolor = [];
  doc.items.forEach((item, n) => {
    if (f.state[index][n] !== 1) return;
    const base = x.length;
    const q = f.quat[index][n], c = f.pos[index][n];
    for (const p of item.hull) {
      const r = rotate(q, p);
      x.push(c[0] + r[0]); y.push(c[1] + r[1]); z.push(c[2] + r[2]);
    }
    const colour = doc.retained[n] ? colours.retained : colours.discharged;
    for (const [a, b, d] of item.faces) {
      i.push(base + a); j.push(base + b); k.push(base + d); facecolor.push(colour);
    }
  });
  return {
    type: "mesh3d", name: "items", hoverinfo: "skip", flatshading: true, x, y, z, i, j, k, facecolor,
    lighting: { ambient: 0.55, diffuse: 0.8, specular: 0.1 },
  };
}

// The vibration direction as a line with a cone for its head, above the back of the tray.
export function vibrationTraces(doc) {
  const vibration = doc.tray.vibration;
  if (!vibration) return [];
  const { lo, hi } = viewBox(doc);
  const start = [lo[0] + 0.06, lo[1] + 0.06, hi[2] - 0.08];
  const d = vibration.direction;
  const end = start.map((s, a) => s + ARROW_LENGTH * d[a]);
  return [
    { type: "scatter3d", mode: "lines", name: "vibration", hoverinfo: "skip", showlegend: false,
      x: [start[0], end[0]], y: [start[1], end[1]], z: [start[2], end[2]], line: { color: ARROW, width: 6 } },
    { type: "cone", name: "vibration", hoverinfo: "skip", showscale: false, anchor: "tip", sizemode: "absolute",
      sizeref: 0.03, colorscale: [[0, ARROW], [1, ARROW]], x: [end[0]], y: [end[1]], z: [end[2]],
      u: [d[0]], v: [d[1]], w: [d[2]] },
  ];
}

// "tilt 3 deg; vibration (arrow) 25 deg from the horizontal, 1.5 mm at 60 Hz from t = 5 s"
export function motionText(doc) {
  const tilt = `tray tilt ${doc.tray.tilt_deg ?? 0} deg`;
  const v = doc.tray.vibration;
  if (!v) return `${tilt}; this run's snapshots do not record the vibration`;
  return `${tilt}; vibration (arrow) ${Math.round(v.angle_deg)} deg from the horizontal, ` +
    `${+(v.amplitude * 1e3).toPrecision(3)} mm at ${v.frequency} Hz from t = ${v.start} s`;
}

export function layout3d(doc) {
  const { lo, hi } = viewBox(doc);
  const span = hi.map((h, a) => h - lo[a]);
  const axis = (title, a) => ({ title: { text: title }, range: [lo[a], hi[a]], backgroundcolor: "#fbfbf8",
    gridcolor: "#e3e6ea", showbackground: true, zeroline: false });
  return baseLayout({
    margin: { l: 0, r: 0, t: 0, b: 0 },
    showlegend: false,
    uirevision: "replay", // the camera a user turned stays where it is while the replay plays
    scene: {
      xaxis: axis("x (m)", 0), yaxis: axis("y (m)", 1), zaxis: axis("z (m)", 2),
      aspectmode: "manual", aspectratio: { x: 1.6, y: (1.6 * span[1]) / span[0], z: (1.6 * span[2]) / span[0] },
      camera: { eye: { x: -0.3, y: -1.4, z: 0.6 }, up: { x: 0, y: 0, z: 1 } },
    },
  });
}

export function draw3d(box, doc, index, colours) {
  const data = [trayTrace(doc, index), itemsTrace(doc, index, colours), ...vibrationTraces(doc)];
  return Plotly.react(box, data, layout3d(doc), CONFIG);
}

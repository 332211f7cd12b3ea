// The dashboard's one door to the JSON API: the API key (kept in localStorage, sent as a bearer
// token, exactly as any other client would), fetch with error reporting, and small formatters.
// Pages import from here; nothing here knows about a particular page.

const KEY_STORAGE = "demcal.apiKey";
export const API = document.body.dataset.api || "/api/v1";

export function apiKey() {
  return localStorage.getItem(KEY_STORAGE) || "";
}

export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.status = status;
  }
}

// FastAPI puts the reason in "detail": a string, or a list of validation errors.
function detailText(body, fallback) {
  if (!body || body.detail === undefined) return fallback;
  if (typeof body.detail === "string") return body.detail;
  if (Array.isArray(body.detail)) {
    return body.detail.map((d) => `${(d.loc || []).join(".")}: ${d.msg}`).join("\n");
  }
  return JSON.stringify(body.detail);
}

// `path` is relative to the API prefix unless `root` is set (the dashboard's own JSON routes).
export async function api(path, { method = "GET", body, headers = {}, raw = false, root = false } = {}) {
  const init = { method, headers: { Accept: "application/json", ...headers } };
  const key = apiKey();
  if (key) init.headers.Authorization = `Bearer ${key}`;
  if (body !== undefined) {
    if (typeof body === "string") {
      init.body = body;
    } else {
      init.body = JSON.stringify(body);
      init.headers["Content-Type"] = "application/json";
    }
  }
  const response = await fetch(root ? path : API + path, init);
  if (!response.ok) {
    let parsed = null;
    try { parsed = await response.json(); } catch { /* not JSON: keep the status text */ }
    const message = detailText(parsed, `${response.status} ${response.statusText}`);
    if (response.status === 401 || response.status === 403) showKeyProblem(message);
    throw new ApiError(response.status, message);
  }
  if (raw) return response;
  if (response.status === 204) return null;
  return response.json();
}

// A list endpoint may answer a bare array or a page object; pages only want the items.
export function itemsOf(body) {
  return Array.isArray(body) ? body : (body.items || []);
}

export function showBanner(message, kind = "error") {
  const banner = document.getElementById("banner");
  banner.textContent = message;
  banner.className = `banner ${kind}`;
  banner.hidden = false;
}

export function clearBanner() {
  document.getElementById("banner").hidden = true;
}

function showKeyProblem(message) {
  showBanner(
    apiKey()
      ? `The API refused the saved key: ${message}. Paste a valid key (demcal apikey create) above.`
      : "This dashboard reads the API with an API key: paste one (from `demcal apikey create`) in the box above.",
    "error",
  );
}

function setupKeyForm() {
  const form = document.getElementById("key-form");
  const input = document.getElementById("api-key");
  const state = document.getElementById("key-state");
  const describe = () => { state.textContent = apiKey() ? "key saved" : "no key"; };
  describe();
  form.addEventListener("submit", (event) => {
    event.preventDefault();
    const value = input.value.trim();
    if (value) localStorage.setItem(KEY_STORAGE, value);
    else localStorage.removeItem(KEY_STORAGE);
    input.value = "";
    describe();
    window.location.reload();
  });
}
setupKeyForm();

// Repeat `task` every `ms` while the tab is visible; a failing poll shows a banner and retries.
// Returns a function that stops it (also when a run is in flight when it is called).
export function poll(task, ms) {
  let timer = null;
  let stopped = false;
  const run = async () => {
    let wait = ms;
    try {
      const next = await task(); // false: stop; a number: the ms until the next run; else ms
      if (next === false) return;
      if (typeof next === "number") wait = next;
    } catch (error) {
      if (!(error instanceof ApiError)) console.error(error);
      showBanner(`Could not refresh: ${error.message}`);
    }
    if (!stopped) timer = setTimeout(run, document.hidden ? wait * 5 : wait);
  };
  run();
  return () => { stopped = true; clearTimeout(timer); };
}

// The study's first experiment (definitions stored before several existed have "experiment").
export function experimentOf(definition) {
  return definition?.experiments?.[0] ?? definition?.experiment;
}

// The first experiment's target with the study's own rule (optimizer/study.py Experiment.target).
export function targetOf(definition) {
  return experimentTarget(experimentOf(definition));
}

function experimentTarget(exp, integer = true) {
  if (!exp?.measured?.length) return NaN;
  const v = [...exp.measured].sort((a, b) => a - b);
  const mid = Math.floor(v.length / 2);
  let value = (exp.aggregate || "median") === "mean"
    ? v.reduce((a, b) => a + b, 0) / v.length
    : (v.length % 2 ? v[mid] : (v[mid - 1] + v[mid]) / 2);
  const rule = exp.round || (integer ? "half_up" : "none");
  if (rule === "half_up") value = Math.floor(value + 0.5);
  else if (rule === "half_even") {
    const floor = Math.floor(value);
    const diff = value - floor;
    value = diff > 0.5 || (diff === 0.5 && floor % 2 === 1) ? floor + 1 : floor;
  }
  return value;
}

// ---- responses ------------------------------------------------------------------------------
// What the study's experiments measured, in their order: each the declaration the API sends with
// the study (`responses`: name, unit, label, from the scenario registry), its experiment and
// target. The pages name and label every response from here, never a scenario of their own.
export function experimentResponses(study) {
  const declared = study?.responses || [];
  const def = study?.definition || {};
  const experiments = def.experiments || (def.experiment ? [def.experiment] : []);
  return experiments.map((experiment) => {
    const name = experiment.response || declared[0]?.name || "n_remaining";
    const response = declared.find((d) => d.name === name) || { name, unit: "1", type: "real", label: name };
    return { ...response, experiment, target: experimentTarget(experiment, response.type === "integer") };
  });
}

const escapeHtml = (text) => text.replace(/&/g, "&amp;").replace(/</g, "&lt;").replace(/>/g, "&gt;");

// Plain text ("N_t", "angle of repose") for tables and captions; plotly's HTML ("N<sub>t</sub>").
export const responseText = (r) => r.label || r.name;
export const responseHtml = (r) => escapeHtml(responseText(r)).replace(/_(\w+)/g, "<sub>$1</sub>");
const pure = (r) => !r.unit || r.unit === "1";
export const unitOf = (r) => (pure(r) ? "–" : r.unit);

// "31.2 deg", "3 items", "0.25" (a pure number has no unit).
export function withUnit(value, r, digits = 3) {
  if (value === null || value === undefined) return "–";
  return pure(r) ? fmt(value, digits) : `${fmt(value, digits)} ${r.unit}`;
}

// A finished run's measured value of a response; null for a run that measured nothing.
export function measuredValue(trial, r) {
  if (trial.status !== "ok") return null;
  const value = trial.responses?.[r.name];
  return value === undefined ? null : value;
}

// plotly.min.js loads with `async`, so code that draws waits for it here.
export function plotlyReady() {
  if (window.Plotly) return Promise.resolve(window.Plotly);
  return new Promise((resolve, reject) => {
    const tag = document.getElementById("plotly-js");
    tag.addEventListener("load", () => resolve(window.Plotly));
    tag.addEventListener("error", () => reject(new Error("could not load /static/vendor/plotly.min.js")));
  });
}

// ---- formatting -----------------------------------------------------------------------------

export function fmt(value, digits = 3) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  if (typeof value !== "number") return String(value);
  if (!Number.isFinite(value)) return value > 0 ? "∞" : "−∞";
  const magnitude = Math.abs(value);
  if (magnitude !== 0 && (magnitude >= 1e5 || magnitude < 1e-3)) return value.toExponential(digits - 1);
  return Number(value.toPrecision(digits)).toString();
}

// The API's latest generation index: 0 is the initial population, -1 means none recorded yet.
export function generationText(generation, total) {
  const latest = generation >= 0 ? String(generation) : "none yet";
  return total ? `${latest} of ${total}` : latest;
}

export function fmtTime(iso) {
  if (!iso) return "–";
  const date = new Date(iso);
  if (Number.isNaN(date.getTime())) return iso;
  return date.toLocaleString(undefined, { dateStyle: "medium", timeStyle: "short" });
}

export function fmtSeconds(s) {
  if (s === null || s === undefined) return "–";
  if (s < 120) return `${fmt(s, 3)} s`;
  if (s < 7200) return `${fmt(s / 60, 3)} min`;
  return `${fmt(s / 3600, 3)} h`;
}

// The items' four, then the optional item-wall ones (dem/parameters.py): a study shows a wall
// parameter only when its definition names it (parametersOf), a trial only when it carries it.
export const PARAMETERS = [
  { key: "E", label: "E", unit: "Pa", title: "Young's modulus E (Pa)", log: true },
  { key: "nu", label: "ν", unit: "–", title: "Poisson's ratio ν (–)", log: false },
  { key: "e", label: "e", unit: "–", title: "restitution e (–)", log: false },
  { key: "mu", label: "μ", unit: "–", title: "friction μ (–)", log: false },
  { key: "E_wall", label: "E_wall", unit: "Pa", title: "walls' Young's modulus E_wall (Pa)", log: true, wall: true },
  { key: "nu_wall", label: "ν_wall", unit: "–", title: "walls' Poisson's ratio ν_wall (–)", log: false, wall: true },
  { key: "e_wall", label: "e_wall", unit: "–", title: "item-wall restitution e_wall (–)", log: false, wall: true },
  { key: "mu_wall", label: "μ_wall", unit: "–", title: "item-wall friction μ_wall (–)", log: false, wall: true },
];

// The parameters of a study (its definition's): the items' four and the wall ones it names.
export function parametersOf(definition) {
  const named = definition?.parameters || {};
  return PARAMETERS.filter((p) => !p.wall || named[p.key] != null);
}

// The parameters a set of values carries (a trial's, a recommendation's).
export function parametersIn(params) {
  return PARAMETERS.filter((p) => !p.wall || params?.[p.key] != null);
}

export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) {
    if (value === undefined || value === null) continue;
    if (name === "class") node.className = value;
    else if (name === "text") node.textContent = value;
    else node.setAttribute(name, value);
  }
  for (const child of children) {
    if (child === null || child === undefined) continue;
    node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
  return node;
}

export function statusBadge(status) {
  return el("span", { class: `status ${status || ""}`, text: status || "–" });
}

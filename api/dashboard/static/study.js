// The study page: header and progress, the Pareto front, the paper's Fig. 5 generation plot,
// progress against simulations, parameters by generation, which parameters the experiment pins
// down, the recommendation, and the pause/resume/cancel/export buttons. Runs that measured
// nothing are drawn apart and counted by status in every plot (plots.js failureCounts).
// Trials are loaded once, then polled incrementally with ?changed_since= (only what changed, by
// the study's change number, which no writer's clock can skew) and upserted by id, so a running
// study costs one small request every few seconds. The recommendation, progress and
// identifiability are read again only when the study changed (its version), or one alone when its last answer was
// a stale one (X-Demcal-View: the server builds a new version in the background and serves the
// old one meanwhile), but not before the Retry-After a stale answer gave (identifiability rests
// between builds: asked every poll meanwhile, it was a third of 50 dashboards' requests); new
// trials alone redraw the recommendation's tables from the trials loaded. A finished study is
// polled until a quiet round and every view current, a stale one asked after its Retry-After.

import {
  ApiError, PARAMETERS, api, apiKey, clearBanner, el, experimentResponses, fmt, fmtTime, generationText,
  itemsOf, measuredValue, parametersIn, parametersOf, poll, plotlyReady, responseHtml, responseText, showBanner, statusBadge, unitOf,
  withUnit,
} from "./api.js";
import {
  CONFIG, generationFigure, paretoFigure, parameterFigure, progressFigure,
} from "./plots.js";

const studyId = document.getElementById("study").dataset.studyId;
const base = `/studies/${encodeURIComponent(studyId)}`;
const PAGE = 5000; // the API's largest page: a 10,000-trial study loads in two requests
const POLL_MS = 3000;
const TERMINAL = new Set(["done", "cancelled", "failed"]);

const trials = new Map();
let generations = []; // GET /generations: each generation's medians and W1, for Fig. 5
let study = null;
let responses = []; // the experiments' responses with units (api.js experimentResponses)
let cursor = null; // the study's change number at the last page: the next poll asks for later ones
const VIEWS = ["recommendation", "progress", "identifiability"];
let viewsRead = null; // the study's version the views were read at
let viewsBeingRead = null; // the promise of the views being read (readViews), if any
const views = {}; // each view's last answer: { body, current, retryAt } (current: not a stale version)

// One request for the first page (it says how many match), then the rest in parallel.
async function loadTrialChanges() {
  const query = (offset) => {
    const q = new URLSearchParams({ limit: PAGE, offset });
    if (cursor !== null) q.set("changed_since", cursor);
    return `${base}/trials?${q}`;
  };
  const first = await api(query(0));
  const offsets = [];
  for (let offset = first.items.length; offset < first.total && first.items.length; offset += PAGE) {
    offsets.push(offset);
  }
  const pages = [first, ...(await Promise.all(offsets.map((offset) => api(query(offset)))))];
  let changed = 0;
  for (const page of pages) {
    for (const t of itemsOf(page)) trials.set(t.id, t);
    changed += page.items.length;
  }
  // The first page's change number was read before any page was: nothing is missed.
  cursor = first.changes;
  return changed;
}

function renderHeader() {
  showWallColumns();
  document.getElementById("study-name").textContent = study.name || study.id;
  document.title = `${study.name || study.id} · demcal`;
  const status = document.getElementById("study-status");
  status.replaceWith(Object.assign(statusBadge(study.status), { id: "study-status" }));
  const p = study.progress;
  const def = study.definition || {};
  const facts = [
    ["Study id", study.id],
    ["Progress", `${p.trials_done} / ${p.trials_total} trials`],
    ["Failed runs", p.failures ? p.failures.text.replace(/^failed: /, "") : "–"],
    ["Generation", generationText(p.generation, p.generations_total)],
    ...responses.flatMap((r) => [
      [`Target ${responseText(r)}`, `${withUnit(r.target, r)} (tolerance ±${fmt(r.experiment.tolerance ?? NaN)})`],
      [`Measured ${responseText(r)}`, (r.experiment.measured || []).join(", ")],
    ]),
    ["Objective f2", def.objective_time === "wall" ? "wall time T of the whole protocol (s)"
      : "cost of the whole protocol (machine-independent)"],
    ["Created", fmtTime(study.created_at)],
    ["Updated", fmtTime(study.updated_at)],
  ];
  const warnings = document.getElementById("study-warnings");
  warnings.hidden = !(study.warnings || []).length;
  warnings.replaceChildren(...(study.warnings || []).map((w) => el("p", { text: `Warning: ${w}` })));
  const dl = document.getElementById("study-facts");
  dl.replaceChildren(...facts.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]));
  if (study.message) dl.append(el("dt", { text: "Message" }), el("dd", { text: study.message }));
  const share = p.trials_total ? (100 * p.trials_done) / p.trials_total : 0;
  document.getElementById("progress-bar").style.width = `${Math.min(100, share)}%`;
  const s = study.status;
  document.getElementById("btn-pause").disabled = !(s === "running" || s === "created");
  document.getElementById("btn-resume").disabled = s !== "paused";
  document.getElementById("btn-cancel").disabled = TERMINAL.has(s);
}

function maxGeneration() {
  const planned = study?.progress?.generations_total ?? 0;
  if (planned > 0) return planned; // batches after the last generation re-measure, they do not search
  let seen = 0;
  for (const t of trials.values()) seen = Math.max(seen, t.generation);
  return seen;
}

// The Pareto front first (it is what the page is for); the two figures below the fold are
// drawn in the next frame so that the front shows up without waiting for them. With
// ``readGenerations`` (the trials changed), the per-generation summary is read meanwhile, once
// per change (a cached view: its ETag makes it a 304 when nothing changed), for Fig. 5's medians
// and W1s.
async function renderPlots(readGenerations = false) {
  const summaries = readGenerations ? api(`${base}/generations`) : null;
  await plotlyReady();
  const list = [...trials.values()];
  const xKey = document.getElementById("pareto-x").value;
  const gmax = maxGeneration();
  // The validation's fresh runs are not the search's: the ranking leaves them out
  // (optimizer/objectives.py), so a failed one does not fail its set here either; the validation
  // table shows them.
  const ranked = list.filter((t) => !isValidationRun(t));
  const validation = list.length - ranked.length;
  const pareto = paretoFigure(ranked, xKey, gmax, responses, study.f1_unit, study.f1_rule);
  Plotly.react("pareto-plot", pareto.data, pareto.layout, CONFIG);
  const caption = document.getElementById("pareto-caption");
  const { unfinished, outside, unranked } = pareto.hidden;
  caption.textContent =
    `${pareto.measured} measured trials, coloured by generation; ` +
    `${pareto.data[1].x.length} Pareto members are outlined diamonds. ` +
    (pareto.counts.total
      ? `Above, apart: ${pareto.counts.text}; their trials (${pareto.failed}) have ${noneText()} and are not ranked. `
      : `Every finished run measured ${measuredText()}. `) +
    "Click a point to open its trial." +
    (unfinished ? ` ${unfinished} trials not shown (not finished yet).` : "") +
    (unranked ? ` ${unranked} finished trials not shown until their batch is ranked.` : "") +
    (outside ? ` ${outside} extra replicates not shown (not ranked yet).` : "") +
    (validation ? ` ${validation} fresh-seed validation runs are in the validation table, not here.` : "");
  if (!performance.getEntriesByName("demcal:pareto-drawn").length) performance.mark("demcal:pareto-drawn");
  await new Promise((resolve) => requestAnimationFrame(() => setTimeout(resolve, 0)));
  // Fig. 5 and the parameters are the search's generations; extra replicates and the validation
  // (later batches) are shown in the recommendation and validation tables.
  const searched = list.filter((t) => t.generation <= gmax);
  // One panel per experiment's response, each as tall as the feeder's single one.
  document.getElementById("generation-plot").style.height = responses.length > 1
    ? `${520 + 300 * (responses.length - 1)}px` : "";
  // If the summary could not be read, the plots are drawn with the last W1s read, and the
  // error is the poll's (its banner) once they are.
  let unread = null;
  if (summaries) generations = await summaries.catch((error) => { unread = error; return generations; });
  const gen = generationFigure(searched, responses, gmax, generations, study.definition?.objective_time);
  Plotly.react("generation-plot", gen.data, gen.layout, CONFIG);
  const par = parameterFigure(searched, study.definition?.parameters || {}, gmax, responses, study.f1_unit);
  Plotly.react("parameter-plot", par.data, par.layout, CONFIG);
  // A point can be clicked as soon as it is drawn, not only once the slower tables have loaded.
  bindClicks();
  // For benchmarks/dashboard_render.py: the first moment every plot of the study is drawn.
  if (!performance.getEntriesByName("demcal:plots-drawn").length) performance.mark("demcal:plots-drawn");
  if (unread) throw unread;
}

// The study's parameters (the items' four and the wall ones it names), as table cells; the tables'
// headers get a column for each wall one after μ (showWallColumns).
function paramCells(params) {
  return parametersOf(study?.definition).map((p) => el("td", { class: "num", text: fmt(params?.[p.key], 4) }));
}

function showWallColumns() {
  for (const mu of document.querySelectorAll("th[data-after-parameters]")) {
    if (mu.dataset.done) continue;
    mu.dataset.done = "1";
    const walls = parametersOf(study?.definition).filter((p) => p.wall);
    mu.after(...walls.map((p) => el("th", { text: `${p.label} (${p.unit})` })));
  }
}

const noneText = () => (responses.length === 1 ? `no ${responseText(responses[0])}` : "no responses");
const measuredText = () => (responses.length === 1 ? responseText(responses[0]) : "every response");

// Values per response as one cell: "2, 3" for one experiment, "angle: 31, 32; N_t: 2, 3" for several.
function valuesText(valuesOf) {
  const shown = (r) => (valuesOf(r) || []).map((v) => fmt(v, 4)).join(", ") || "–";
  return responses.length === 1 ? shown(responses[0])
    : responses.map((r) => `${responseText(r)}: ${shown(r)}`).join("; ");
}

// The measured responses of every run of an individual (its replicates), from the trials loaded.
// The batch of fresh-seed validation runs, as the API numbers it (StudyDefinition.validation_batch).
const isValidationRun = (t) => t.generation === study?.progress?.validation_batch;

// A set's runs in the search (its fresh-seed validation runs are in the validation table).
function runsOf(individual) {
  const runs = [...trials.values()].filter(
    (t) => t.individual === individual && t.state === "done" && !isValidationRun(t));
  const values = (r) => runs.map((t) => measuredValue(t, r)).filter((v) => v !== null);
  return { runs: runs.length, text: valuesText(values), measured: responses.some((r) => values(r).length) };
}

// A table header naming the responses ("N<sub>t</sub> per run"), written as plotly's labels are.
function headerHtml(th, suffix, prefix = "") {
  const name = responses.length === 1 ? responseHtml(responses[0]) : "responses";
  th.innerHTML = `${prefix}${name}${suffix}`;
}

const interval = (pair, digits = 2) => (pair ? `[${fmt(pair[0], digits)}–${fmt(pair[1], digits)}]` : "");
const VALIDATION_CLASS = { validated: "ok", "not reproduced": "failed", "not validated": "paused", pending: "pending" };
const VALIDATION_TEXT = { pending: "pending: fresh seeds when the search ends" };
// What the recommendation is, by its validation status (optimizer/validation.py); a set not
// validated (validation.seeds = 0, or the search still running) is introduced as a search's match.
const INTRO = {
  validated: "The fastest validated parameter set (fresh seeds, table below):",
  "not reproduced": "No candidate reproduced the experiment on fresh seeds (table below); the fastest match of the search:",
};

// How the driver chose the recommendation after the validation (optimizer/driver.py _chosen_by);
// studies stored before it said so read INTRO.
function chosenBy(rec) {
  if (!rec.chosen_by) return "";
  const text = `${rec.chosen_by[0].toUpperCase()}${rec.chosen_by.slice(1)}`;
  return rec.validation_status === "validated" ? `${text} (fresh seeds, table below):` : `${text}:`;
}

// A polled view's JSON, whether the server said it is of the study's current version, and for a
// stale one when a newer one can be ready at the earliest (Date.now() time; 0: ask at any poll).
async function view(path) {
  const response = await api(path, { raw: true });
  const current = response.headers.get("X-Demcal-View") !== "stale";
  const retryAfter = Number(response.headers.get("Retry-After"));
  const retryAt = !current && retryAfter > 0 ? Date.now() + retryAfter * 1000 : 0;
  return { body: await response.json(), current, retryAt };
}

function renderRecommendation(body) {
  const box = document.getElementById("recommendation");
  const rec = body.recommendation;
  if (!rec) {
    box.replaceChildren(el("p", { class: "muted", text:
      TERMINAL.has(body.status) ? "No parameter set matched the experiment within tolerance."
        : "No recommendation yet: it appears once a trial matches the experiment within tolerance." }));
  } else {
    const params = rec.params || {};
    const rows = parametersIn(params).map((p) => [p.title, fmt(params[p.key], 4)]);
    for (const r of responses) {
      // optimizer.pareto.summary: each experiment's response per replicate (older: N_t only).
      const values = rec.responses?.[r.name] ?? (r.name === "n_remaining" ? rec.n_remaining : undefined);
      const label = `${responseText(r)}`;
      if (Array.isArray(values)) rows.push([`${label} per replicate (${unitOf(r)})`, values.map((v) => fmt(v, 4)).join(", ") || "–"]);
      else if (values !== undefined && values !== null) rows.push([`${label} (${unitOf(r)})`, fmt(values, 4)]);
    }
    if (rec.f1 !== undefined && rec.f1 !== null) {
      // The search runs' f1: after the validation a candidate chosen on its pooled neighbours can lie
      // outside the tolerance on its own runs; its fresh f1 is in the validation table.
      rows.push([`f1 of its search runs (${unitOf({ unit: study.f1_unit })})`, `${fmt(rec.f1, 3)} ${interval(rec.f1_interval)}`.trim()]);
    }
    if (rec.replicates) rows.push(["replicates in the search", String(rec.replicates)]);
    // optimizer.pareto.summary: the set's f2 parts, of the whole protocol (mean over replicates).
    for (const [key, label] of [["wall_time_s", "T of the whole protocol (s)"], ["cost", "cost of the whole protocol"]]) {
      if (rec[key] !== undefined && rec[key] !== null) rows.push([label, fmt(rec[key], 4)]);
    }
    const trialId = (rec.trial_ids || [])[0]; // optimizer.pareto.summary: every replicate of the set
    const dl = el("dl", { class: "facts" }, ...rows.flatMap(([k, v]) => [el("dt", { text: k }), el("dd", { text: v })]));
    const verdict = rec.validation_status; // a study that ended before its check stores "not validated"
    box.replaceChildren(
      el("p", { text: chosenBy(rec) || INTRO[verdict] || (responses.length === 1
        ? `The fastest Pareto member whose ${responseText(responses[0])} matches the experiment within tolerance:`
        : "The fastest Pareto member whose responses match every experiment within tolerance:") }),
      verdict ? el("p", { id: "validation-status" }, "Validation: ",
        el("span", { class: `status ${VALIDATION_CLASS[verdict] || ""}`, text: VALIDATION_TEXT[verdict] || verdict })) : null,
      dl,
      trialId ? el("p", {}, el("a", { href: `/trials/${encodeURIComponent(trialId)}`, text: `open trial ${trialId}` })) : null,
    );
  }
  renderValidation(rec?.validation || [], responses[0]?.experiment?.measured || []);
  headerHtml(document.getElementById("equivalent-response"), " per search run");
  // The sets are sorted on f2, so the column shows f2 as ranked: T or cost of the whole protocol.
  document.getElementById("equivalent-f2").textContent =
    study?.definition?.objective_time === "wall" ? "T of the whole protocol (s)" : "cost of the whole protocol";
  const tbody = document.querySelector("#equivalent tbody");
  const rows = (body.equivalent || []).map((t) => {
    const { runs, text, measured } = runsOf(t.individual);
    return el("tr", {},
      el("td", {}, el("a", { href: `/trials/${encodeURIComponent(t.id)}`, text: `g${t.generation} · i${t.individual}` })),
      ...paramCells(t.params),
      el("td", { class: "num", text: measured ? text : "–" }),
      el("td", { class: "num", text: String(runs) }),
      el("td", { class: "num", text: fmt(t.f2) }));
  });
  tbody.replaceChildren(...(rows.length ? rows
    : [el("tr", {}, el("td", { colspan: 4 + parametersOf(study?.definition).length, class: "muted", text: "None yet." }))]));
}

// The validation that ends a study (optimizer/validation.py): each candidate's fresh-seed values
// of the first experiment's response (its "n_remaining" field, whatever the response) against
// the experiment, with W1, the median and f1 with their bootstrap intervals.
// A GA ranked on pooled neighbours (ga.match_estimate) chose its candidates on their pooled W1:
// shown beside the set's own f1, starred when that estimate called the set feasible.
function searchF1(row) {
  if (row.search_pooled_w1 == null) return fmt(row.search_f1, 3);
  const star = row.search_pooled_violation <= 0 ? "*" : "";
  return `${fmt(row.search_f1, 3)} · pooled W1 ${fmt(row.search_pooled_w1, 3)}${star}`;
}

function renderValidation(rows, measured) {
  const section = document.getElementById("validation");
  section.hidden = rows.length === 0;
  if (!rows.length) return;
  const sorted = [...measured].sort((a, b) => a - b);
  const mid = Math.floor(sorted.length / 2);
  const median = sorted.length % 2 ? sorted[mid] : (sorted[mid - 1] + sorted[mid]) / 2;
  document.getElementById("validation-caption").textContent =
    `Experiment: ${responseText(responses[0])} ${measured.join(", ")} (median ${fmt(median)}). ` +
    "Each candidate re-simulated on " +
    "seeds never used in the search; validated when every fresh run measured and the fresh runs " +
    "cannot be told apart from the experiment (a permutation test at the 90 % level; " +
    "with few measured values it has little power: read W1 and the median too).";
  headerHtml(document.getElementById("validation-response"), "", "fresh ");
  document.querySelector("#validation-table tbody").replaceChildren(...rows.map((row) => el("tr",
    { "data-individual": row.individual },
    el("td", { text: `i${row.individual}` }),
    ...paramCells(row.params),
    el("td", { class: "num", text: searchF1(row) }),
    el("td", { class: "num", text: (row.n_remaining || []).join(", ") +
      (row.failures?.length ? ` + ${row.failures.length} failed` : "") }),
    el("td", { class: "num", text: `${fmt(row.median)} ${interval(row.median_interval)}`.trim() }),
    el("td", { class: "num", text: fmt(row.w1, 3) }),
    el("td", { class: "num", text: `${fmt(row.f1, 3)} ${interval(row.f1_interval)}`.trim() }),
    el("td", {}, el("span", { class: `status ${VALIDATION_CLASS[row.verdict] || ""}`, text: row.verdict })))));
}

async function renderProgress(progress) {
  await plotlyReady();
  const figure = progressFigure(progress, study.f1_unit);
  Plotly.react("progress-plot", figure.data, figure.layout, CONFIG);
  document.getElementById("progress-caption").textContent = figure.caption;
}

const VERDICT_CLASS = { pinned: "ok", weak: "paused", "not identifiable": "failed" };

function verdictBadge(verdict, text) {
  return el("span", { class: `status ${VERDICT_CLASS[verdict] || ""}`, text: text || verdict });
}

function renderIdentifiability(identified) {
  const entries = identified.parameters || [];
  // Several experiments: the verdict is theirs together; each one's own verdict is in a second
  // table, so that a parameter pinned only by the experiments together says so.
  const alone = (identified.experiments || []).filter((x) => x.parameters.length);
  const several = alone.length > 1;
  const label = (name) => {
    const response = responses.find((r) => r.name === name);
    return response ? responseText(response) : name;
  };
  const title = (name) => PARAMETERS.find((q) => q.key === name)?.title || name;
  document.getElementById("identifiability-basis").textContent = entries.length
    ? `From ${identified.simulations} successful simulations: ${several
      ? `each experiment's response modelled on its own (${alone.map((x) => label(x.response)).join("; ")});` +
        " the verdict is the experiments' together, from the sets that match them all"
      : identified.method}.`
    : (identified.reason || "Not available yet.");
  const rows = entries.map((entry) => {
    const range = entry.matching_range;
    return el("tr", { "data-parameter": entry.name },
      el("td", { text: title(entry.name) }),
      el("td", {}, verdictBadge(entry.verdict, entry.pinned_together ? "pinned together" : entry.verdict)),
      el("td", { class: "num", text: fmt(entry.total, 2) }),
      el("td", { class: "num", text: fmt(entry.first_order, 2) }),
      el("td", { class: "num", text: fmt(entry.matching_spread, 2) }),
      el("td", { class: "num", text: range ? `${fmt(range[0], 3)} – ${fmt(range[1], 3)}` : "–" }));
  });
  document.querySelector("#identifiability tbody").replaceChildren(...(rows.length ? rows
    : [el("tr", {}, el("td", { colspan: 6, class: "muted", text: "None yet." }))]));
  const table = document.getElementById("identifiability-alone");
  table.hidden = !several;
  if (!several) return;
  table.querySelector("thead tr").replaceChildren(el("th", { text: "Parameter" }),
    ...alone.map((x) => el("th", { text: label(x.response) })));
  const own = (x, name) => x.parameters.find((q) => q.name === name).verdict;
  table.querySelector("tbody").replaceChildren(...entries.map((entry) =>
    el("tr", { "data-parameter": entry.name }, el("td", { text: title(entry.name) }),
      ...alone.map((x) => el("td", {}, verdictBadge(own(x, entry.name)))))));
}

// How each polled view (VIEWS) is drawn.
const RENDER_VIEW = {
  recommendation: renderRecommendation,
  progress: renderProgress,
  identifiability: renderIdentifiability,
};

async function refresh() {
  const first = study === null;
  let changed;
  if (first) {
    // The first load reads the study and the trials at once. Later polls read the study first:
    // a study seen finished must not stop polling before its last trial changes were read.
    [study, changed] = await Promise.all([api(base), loadTrialChanges()]);
    responses = experimentResponses(study);
    const measured = responses.length === 1 ? responseText(responses[0]) : "the most sensitive response";
    document.getElementById("identifiability-help").textContent =
      `Total index: the share of ${measured}'s variance over the search box due to the parameter, ` +
      `interactions included (near 0: no experiment on ${measured} can tell its value). Matching ` +
      "spread: the matching sets' range as a share of the searched range (near 1: any value in the " +
      "bounds reproduces the experiments).";
    // Pareto membership is computed on the study's own f2, so show that axis first.
    document.getElementById("pareto-x").value =
      study.definition?.objective_time === "wall" ? "wall_time_s" : "cost";
    renderHeader();
  } else {
    study = await api(base);
    renderHeader();
    changed = await loadTrialChanges();
  }
  if (changed) await renderPlots(true);
  clearBanner();
  const reading = viewsBeingRead ? [] : readViews();
  // The recommendation's tables count each set's runs in the trials loaded: redrawn when they change.
  if (changed && views.recommendation && !reading.includes("recommendation")) {
    renderRecommendation(views.recommendation.body);
  }
  // Keep polling a finished study until one quiet round has confirmed the last changes and every
  // view it shows is current: a stale one (identifiability resting between builds) is asked for
  // again once its Retry-After has passed, and no sooner.
  if (!TERMINAL.has(study.status) || changed !== 0) return true;
  if (viewsBeingRead) await viewsBeingRead;
  const stale = VIEWS.filter((name) => !views[name]?.current);
  if (!stale.length) return false;
  const retryAt = Math.min(...stale.map((name) => views[name]?.retryAt ?? 0));
  return Math.max(POLL_MS, retryAt - Date.now());
}

// Reads the views that are due, in the background: the trials' poll goes on meanwhile (a view's
// first build can take seconds on a long study, and new results must not wait behind it), and
// each view is drawn as soon as it arrives (the recommendation and progress do not wait for
// identifiability; the page said "No recommendation yet" meanwhile, for a study that had one).
// Due: every view when the study changed; otherwise those last answered with a stale version;
// neither before the time a stale answer gave (the server would answer it again as it was).
// Returns the names being read.
function readViews() {
  const version = study.version;
  const due = VIEWS.filter((name) => (version !== viewsRead || !views[name]?.current)
    && !(views[name] && Date.now() < views[name].retryAt));
  if (!due.length) return due;
  viewsBeingRead = Promise.all(due.map(async (name) => {
    views[name] = await view(`${base}/${name}`);
    await RENDER_VIEW[name](views[name].body);
  })).then(() => { viewsRead = version; }, (error) => {
    if (!(error instanceof ApiError)) console.error(error);
    showBanner(`Could not refresh: ${error.message}`);
  }).finally(() => { viewsBeingRead = null; });
  return due;
}

async function act(action) {
  try {
    study = await api(`${base}/${action}`, { method: "POST" });
    renderHeader();
  } catch (error) {
    showBanner(`Could not ${action} the study: ${error.message}`);
  }
}

async function exportAs(format) {
  try {
    const response = await api(`${base}/export.${format}`, { raw: true });
    const blob = await response.blob();
    const link = el("a", { href: URL.createObjectURL(blob), download: `${studyId}-trials.${format}` });
    document.body.append(link);
    link.click();
    link.remove();
    setTimeout(() => URL.revokeObjectURL(link.href), 10000);
  } catch (error) {
    showBanner(`Could not export: ${error.message}`);
  }
}

function wire() {
  document.getElementById("btn-pause").addEventListener("click", () => act("pause"));
  document.getElementById("btn-resume").addEventListener("click", () => act("resume"));
  document.getElementById("btn-cancel").addEventListener("click", () => {
    if (window.confirm("Cancel this study? Queued and running trials are stopped.")) act("cancel");
  });
  document.getElementById("btn-export-csv").addEventListener("click", () => exportAs("csv"));
  document.getElementById("btn-export-json").addEventListener("click", () => exportAs("json"));
  document.getElementById("pareto-x").addEventListener("change", () => { renderPlots(); });
}

// Clicking a trial point (in any plot) opens its trial; customdata[0] is the trial id. Plotly
// adds .on() to a div at its first draw, so this runs after the first render.
function bindClicks() {
  for (const id of ["pareto-plot", "generation-plot", "parameter-plot"]) {
    const div = document.getElementById(id);
    if (div.dataset.clickBound) continue;
    div.dataset.clickBound = "1";
    div.on("plotly_click", (event) => {
      const point = event.points?.[0];
      const trialId = point?.customdata?.[0];
      if (trialId) window.location.href = `/trials/${encodeURIComponent(trialId)}`;
    });
  }
}

async function start() {
  wire();
  if (!apiKey()) {
    showBanner("Paste an API key (from `demcal apikey create`) in the box above to see this study.", "warn");
    return;
  }
  poll(refresh, POLL_MS);
}

start().catch((error) => {
  if (!(error instanceof ApiError)) console.error(error);
  showBanner(error.message);
});

// The studies page: one row per study with status, progress, generation, the recommendation so
// far and its times; refreshed every few seconds. The list endpoint is compact, so the details
// (recommendation) are fetched per study only when its updated_at changed since the last look.

import { PARAMETERS, api, apiKey, clearBanner, el, fmt, fmtTime, itemsOf, poll, showBanner, statusBadge } from "./api.js";

const POLL_MS = 4000;
const TERMINAL = new Set(["done", "cancelled", "failed"]);
const details = new Map(); // study id -> { updated_at, study }

async function detailOf(item) {
  const known = details.get(item.id);
  if (known && known.updated_at === item.updated_at) return known.study;
  const study = await api(`/studies/${encodeURIComponent(item.id)}`);
  details.set(item.id, { updated_at: item.updated_at, study });
  return study;
}

function recommendationText(study) {
  const rec = study?.recommendation;
  if (rec?.params) {
    return PARAMETERS.map((p) => `${p.label} = ${fmt(rec.params[p.key])}`).join(", ");
  }
  const best = study?.best;
  if (best) {
    return `best so far (f1 = ${fmt(best.f1)} items): ` +
      PARAMETERS.map((p) => `${p.label} = ${fmt(best.params[p.key])}`).join(", ");
  }
  return "–";
}

function row(item, study) {
  const share = item.trials_total ? Math.min(100, (100 * item.trials_done) / item.trials_total) : 0;
  const link = el("a", { href: `/studies/${encodeURIComponent(item.id)}`, text: item.name || item.id });
  const progress = study?.progress;
  return el("tr", { "data-study-id": item.id },
    el("td", {}, link, el("div", { class: "muted", text: item.id })),
    el("td", {}, statusBadge(item.status)),
    el("td", {}, `${item.trials_done} / ${item.trials_total}`,
      el("span", { class: "mini-progress" }, el("span", { style: `width: ${share}%` }))),
    el("td", { text: progress ? `${progress.generation} of ${progress.generations_total}` : String(item.generation) }),
    el("td", { text: recommendationText(study) }),
    el("td", { text: fmtTime(item.created_at) }),
    // The API has no finish time; a finished study's last update is the status change that ended it.
    el("td", { text: TERMINAL.has(item.status) ? fmtTime(item.updated_at) : "–" }),
  );
}

async function refresh() {
  const status = document.getElementById("status-filter").value;
  const query = new URLSearchParams({ limit: 100 });
  if (status) query.set("status", status);
  const page = await api(`/studies?${query}`);
  const items = itemsOf(page);
  const studies = await Promise.all(items.map(detailOf));
  const tbody = document.querySelector("#studies tbody");
  tbody.replaceChildren(...(items.length
    ? items.map((item, i) => row(item, studies[i]))
    : [el("tr", {}, el("td", { colspan: 7, class: "muted" },
        "No studies yet. Create one on ", el("a", { href: "/new", text: "New study" }),
        " or run `demcal calibrate STUDY.toml`."))]));
  const shown = page.total > items.length ? `newest ${items.length} of ${page.total} studies` : `${items.length} studies`;
  document.getElementById("updated").textContent = `${shown} · updated ${new Date().toLocaleTimeString()}`;
  clearBanner();
}

if (!apiKey()) {
  showBanner("Paste an API key (from `demcal apikey create`) in the box above to list your studies.", "warn");
} else {
  let stop = poll(refresh, POLL_MS);
  document.getElementById("status-filter").addEventListener("change", () => {
    stop();
    stop = poll(refresh, POLL_MS);
  });
}

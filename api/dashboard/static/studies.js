// The studies page: one row per study with status, progress, generation, the recommendation so
// far (or the best f1 so far) and its start and finish times; refreshed every few seconds. One
// request per refresh: the list items carry everything the table shows.

import {
  api, apiKey, clearBanner, el, fmt, fmtTime, generationText, itemsOf, parametersIn, poll, showBanner, statusBadge,
  withUnit,
} from "./api.js";

const POLL_MS = 4000;

function paramsText(params) {
  return parametersIn(params).map((p) => `${p.label} = ${fmt(params[p.key])}`).join(", ");
}

function recommendationText(item) {
  const rec = item.recommendation;
  if (rec?.params) return paramsText(rec.params);
  if (item.best_f1 !== null && item.best_f1 !== undefined) {
    return `no match yet; best f1 so far ${withUnit(item.best_f1, { unit: item.f1_unit })}`;
  }
  return "–";
}

function row(item) {
  const share = item.trials_total ? Math.min(100, (100 * item.trials_done) / item.trials_total) : 0;
  const link = el("a", { href: `/studies/${encodeURIComponent(item.id)}`, text: item.name || item.id });
  const generation = generationText(item.generation, item.generations_total);
  return el("tr", { "data-study-id": item.id },
    el("td", {}, link, el("div", { class: "muted", text: item.id })),
    el("td", {}, statusBadge(item.status)),
    el("td", {}, `${item.trials_done} / ${item.trials_total}`,
      el("span", { class: "mini-progress" }, el("span", { style: `width: ${share}%` })),
      item.failures?.total ? el("div", { class: "muted failed-runs", text: item.failures.text }) : null),
    el("td", { text: generation }),
    el("td", { class: "recommendation", text: recommendationText(item) }),
    el("td", { text: fmtTime(item.created_at) }),
    el("td", { text: fmtTime(item.started_at) }),
    el("td", { text: fmtTime(item.finished_at) }),
  );
}

async function refresh() {
  const status = document.getElementById("status-filter").value;
  const query = new URLSearchParams({ limit: 100 });
  if (status) query.set("status", status);
  const page = await api(`/studies?${query}`);
  const items = itemsOf(page);
  const tbody = document.querySelector("#studies tbody");
  tbody.replaceChildren(...(items.length
    ? items.map(row)
    : [el("tr", {}, el("td", { colspan: 8, class: "muted" },
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

// The new-study form: a TOML or JSON study definition (typed, pasted or uploaded) is sent to
// POST /api/v1/studies, the same endpoint every client uses. TOML is first turned into JSON by
// POST /dashboard/definition, because browsers cannot parse TOML without a library.

import { api, apiKey, el, showBanner } from "./api.js";

// examples/study-quick.toml with its scenario (examples/feeder-quick.toml) inline: the server
// reads no file a request names, so scenario_path cannot be used here.
const STARTER = `# A calibration study: what to simulate, what to search, what to match.
# The same document \`demcal calibrate\` reads, with the feeder configuration inline as [scenario].
name = "quick-feeder"
description = "A demonstration study on the 10-item quick feeder"
seed = 1
replicates = 1
objective_time = "cost"   # f2: "cost" (machine-independent) or "wall" (T in seconds, as the paper)
trial_timeout_s = 300

[parameters]
E = { low = 1.0e5, high = 3.0e6 }   # Pa, searched on a log scale
nu = { fixed = 0.3 }
e = { low = 0.1, high = 0.9 }
mu = { low = 0.1, high = 1.0 }

[experiment]
measured = [0, 1, 1, 2, 2, 3, 5]   # N_t of each experiment (items left in the tray)
aggregate = "median"
round = "half_up"
tolerance = 0.5

[ga]
population = 8
offspring = 4
generations = 3

[scenario.items]
counts = { smartphone = 4, feature_phone = 3, camera = 3 }

[scenario.stages]
insertion_time = 0.5
vibration_start = 2.0
vibration_time = 6.0
`;

const form = document.getElementById("new-study");
const text = document.getElementById("definition");
const format = document.getElementById("definition-format");
const result = document.getElementById("new-result");
text.value = STARTER;

document.getElementById("definition-file").addEventListener("change", async (event) => {
  const file = event.target.files[0];
  if (!file) return;
  text.value = await file.text();
  format.value = file.name.toLowerCase().endsWith(".json") ? "json" : "toml";
});

form.addEventListener("submit", async (event) => {
  event.preventDefault();
  result.replaceChildren();
  if (!apiKey()) {
    showBanner("Paste an API key (from `demcal apikey create`) in the box above first.", "warn");
    return;
  }
  let definition;
  try {
    if (format.value === "json") {
      definition = JSON.parse(text.value);
    } else {
      definition = await api("/dashboard/definition", {
        method: "POST", body: text.value, headers: { "Content-Type": "application/toml" }, root: true,
      });
    }
  } catch (error) {
    result.replaceChildren(el("pre", { class: "errors", text: `Could not read the definition: ${error.message}` }));
    return;
  }
  try {
    const study = await api("/studies", { method: "POST", body: definition });
    result.replaceChildren(el("p", {}, "Created ",
      el("a", { href: `/studies/${encodeURIComponent(study.id)}`, text: study.name || study.id }), "."));
    window.location.href = `/studies/${encodeURIComponent(study.id)}`;
  } catch (error) {
    result.replaceChildren(el("pre", { class: "errors", text: `The API refused the study:\n${error.message}` }));
  }
});

// The new-study form: a TOML or JSON study definition (typed, pasted or uploaded) is sent to
// POST /api/v1/studies, the same endpoint every client uses. TOML is first turned into JSON by
// POST /dashboard/definition, because browsers cannot parse TOML without a library.

import { api, apiKey, el, showBanner } from "./api.js";

// examples/study-quick.toml verbatim (tests/dashboard/test_dashboard_routes.py keeps them equal):
// a real calibration, a hidden truth that clogs, found and validated in a few minutes. Its
// scenario is inline: the server reads no file a request names, so scenario_path cannot be used.
const STARTER = `# The README's main job: a real calibration in a few minutes on 2 cores. A synthetic experiment
# with a known truth that clogs (E = 5e6 Pa, e = 0.5, mu = 0.5: after 2.5 s of vibration about
# about half of the 10 items are still in the tray), measured on 8 seeds the study never uses
# (docs/figures.py); the study must find a set that reproduces it and validate it
# on fresh seeds. 8 + 3 x 4 = 20 individuals x 3 replicates (common seeds), up to 4 extra
# replicates for promising sets, then the 2 fastest matching sets on 8 fresh seeds each.
# Run it:  demcal calibrate examples/study-quick.toml      (Ctrl-C, then --resume ID, continues)
#
# The time step is derived from E (a fraction of the shortest contact period), so a softer E gives
# a longer step and a cheaper simulation: that is what f2 (cost) rewards, as in the paper.
# Trials keep their snapshots (keep_snapshots) so the dashboard can replay any of them.

name = "quick-feeder"
description = "Find and validate a hidden truth that clogs the 10-item quick feeder"
seed = 1
replicates = 3                      # f1 = W1 of 3 common-seed runs to the 8 measured values
max_replicates = 4                  # sets that match, or nearly, earn a 4th before recommendation
objective_time = "cost"
trial_timeout_s = 120               # a quick simulation takes about 2-10 s
keep_snapshots = true

[scenario.params]
E = 1.0e7
nu = 0.3
e = 0.5
mu = 0.5

[scenario.items]
counts = { smartphone = 4, feature_phone = 3, camera = 3 }
spread = 0.05
resolution = 12

[scenario.stages]
insertion_time = 0.5
vibration_start = 1.5
vibration_time = 2.5

[scenario.vibration]
frequency = 60.0
amplitude = 1.5e-3
amplitude_kind = "peak"
angle_deg = 25.0

[scenario.run]
stop_when_empty = true

[parameters]
E = { low = 3.0e6, high = 3.0e7 }   # Pa, log10 scale; softer is invalid at insertion
nu = { fixed = 0.3 }                # N_t hardly depends on nu; fixing it saves budget
e = { low = 0.1, high = 0.9 }
mu = { low = 0.1, high = 1.0 }

[experiment]
# The truth (E = 5e6 Pa, nu = 0.3, e = 0.5, mu = 0.5) on seeds 900001-900008:
# python docs/figures.py
measured = [9, 8, 0, 8, 4, 10, 1, 7]
aggregate = "median"
round = "half_up"
# distance = "auto": Wasserstein-1 with 3 replicates; tolerance = the experiment's noise floor

[validation]
seeds = 8                           # fresh seeds per candidate, never used in the search
candidates = 2

[ga]
algorithm = "nsga2"
population = 8
offspring = 4
generations = 3
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

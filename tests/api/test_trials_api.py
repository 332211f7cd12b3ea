"""A finished study read over HTTP: trial pages and filters, incremental polling, the Pareto front,
the per-generation summary (Fig. 5), the recommendation and the exports."""

from __future__ import annotations

import csv
import io
import statistics

import pytest
from scipy.stats import wasserstein_distance

from optimizer.driver import Driver
from optimizer.generations import experiment_band
from optimizer.memory import SyntheticExecutor
from optimizer.objectives import f1_rule
from optimizer.study import StudyDefinition
from tests.api.conftest import study_definition


@pytest.fixture
def finished(store, keys):
    """A study of 6 + 3 x 2 individuals run to completion by the real driver on synthetic results."""
    definition = StudyDefinition.model_validate(
        study_definition(ga={"population": 6, "offspring": 3, "generations": 2}, seed=5)
    )
    study_id = store.create_study(definition.model_dump(mode="json"), owner="alice")
    Driver(store, SyntheticExecutor()).run_to_completion(study_id, poll_timeout=0)
    return study_id


def test_trial_list_pages_and_filters(client, keys, finished):
    url = f"/api/v1/studies/{finished}/trials"

    everything = client.get(url, params={"limit": 100}, headers=keys.auth()).json()
    page = client.get(url, params={"limit": 5, "offset": 10}, headers=keys.auth()).json()
    generation_1 = client.get(url, params={"generation": 1}, headers=keys.auth()).json()
    pareto = client.get(url, params={"pareto": True}, headers=keys.auth()).json()

    assert everything["total"] == 12
    assert len(page["items"]) == 2
    assert {item["generation"] for item in generation_1["items"]} == {1}
    assert generation_1["total"] == 3
    assert pareto["total"] >= 1 and all(item["pareto"] for item in pareto["items"])
    first = everything["items"][0]
    plotted = {"params", "n_remaining", "wall_time_s", "cost", "f1", "f2", "generation", "pareto", "status"}
    assert plotted <= set(first)
    assert first["f1"] is not None


def test_polling_with_changed_since_returns_only_changed_trials(client, keys, store, finished):
    from dataclasses import replace

    from optimizer.protocols import trial_id

    url = f"/api/v1/studies/{finished}/trials"
    first = client.get(url, headers=keys.auth()).json()
    template = store.trials(finished)[0].spec
    changed = trial_id(finished, 99, 0)
    store.add_trials([replace(template, trial_id=changed, individual=99, generation=3)])

    later = client.get(url, params={"changed_since": first["changes"]}, headers=keys.auth()).json()

    assert [item["id"] for item in later["items"]] == [changed]


def test_a_poll_does_not_miss_a_result_written_by_a_process_whose_clock_is_behind(
    client, keys, store, monkeypatch
):
    # The dashboard polled with the previous page's server time (updated_since) and the study's
    # version was the newest trial's updated_at: a result stamped earlier by a writer whose clock
    # is behind fell before both, and the page never showed it. Change numbers cannot.
    from datetime import timedelta

    import api.store.trials as trial_writes
    from optimizer.memory import synthetic_result
    from optimizer.protocols import TrialOutcome, TrialSpec, trial_id

    study_id = store.create_study(study_definition(), owner="alice")
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
    specs = [TrialSpec(trial_id(study_id, i, 0), study_id, i, 0, 0, i, params, {}) for i in range(2)]
    store.add_trials(specs)
    url = f"/api/v1/studies/{study_id}/trials"
    poll = lambda since: client.get(url, params=since, headers=keys.auth()).json()  # noqa: E731
    study = lambda: client.get(f"/api/v1/studies/{study_id}", headers=keys.auth()).json()  # noqa: E731
    page = poll({"limit": 1})
    store.record_result(TrialOutcome(specs[0].trial_id, synthetic_result(specs[0])))
    page = poll({"changed_since": page["changes"]})
    before = study()["progress"]["trials_done"]
    clock = trial_writes.utcnow
    monkeypatch.setattr(trial_writes, "utcnow", lambda: clock() - timedelta(seconds=5))
    store.record_result(TrialOutcome(specs[1].trial_id, synthetic_result(specs[1])))  # 5 s behind
    monkeypatch.undo()

    late = poll({"changed_since": page["changes"]})

    assert [item["id"] for item in page["items"]] == [specs[0].trial_id]
    assert [item["id"] for item in late["items"]] == [specs[1].trial_id]
    assert late["items"][0]["state"] == "done"
    assert (before, study()["progress"]["trials_done"]) == (1, 2)


def test_one_trial_has_its_full_result(client, keys, store, finished):
    trial = store.trials(finished)[0]

    response = client.get(f"/api/v1/studies/{finished}/trials/{trial.spec.trial_id}", headers=keys.auth())
    missing = client.get(f"/api/v1/studies/{finished}/trials/nope", headers=keys.auth())

    assert response.status_code == 200
    assert response.json()["result"]["n_remaining"] == trial.result.n_remaining
    assert missing.status_code == 404


def test_pareto_front_lists_the_flagged_trials_best_f1_first(client, keys, store, finished):
    flagged = {row.id for row in store.pareto_rows(finished)}

    front = client.get(f"/api/v1/studies/{finished}/pareto", headers=keys.auth()).json()

    assert {point["id"] for point in front["points"]} == flagged
    f1 = [point["f1"] for point in front["points"]]
    assert f1 == sorted(f1)
    assert front["generation"] == 2  # initial population + 2 generations: latest index 2


def test_generation_summary_gives_median_and_spread_per_generation(client, keys, store, finished):
    n_t_gen0 = [r.result.n_remaining for r in store.trials(finished) if r.spec.generation == 0]

    summary = client.get(f"/api/v1/studies/{finished}/generations", headers=keys.auth()).json()

    assert [g["generation"] for g in summary] == [0, 1, 2]
    assert [g["trials"] for g in summary] == [6, 3, 3]
    assert summary[0]["n_remaining"]["median"] == statistics.median(n_t_gen0)
    assert summary[0]["n_remaining"]["min"] == min(n_t_gen0)
    wall = summary[0]["wall_time_s"]
    assert wall["q1"] <= wall["median"] <= wall["q3"]
    measured = StudyDefinition.model_validate(store.load_study(finished).definition).experiment.measured
    assert summary[0]["w1_to_experiment"]["n_remaining"] == pytest.approx(
        wasserstein_distance(n_t_gen0, measured)
    )
    band = experiment_band(measured, len(n_t_gen0))
    band["alike"] = wasserstein_distance(n_t_gen0, measured) <= band["w1_95"]
    assert summary[0]["as_experiment"]["n_remaining"] == pytest.approx(band)


def test_recommendation_and_equivalent_sets_are_within_tolerance(client, keys, store, finished):
    body = client.get(f"/api/v1/studies/{finished}/recommendation", headers=keys.auth()).json()

    assert body["recommendation"] == store.load_study(finished).recommendation
    assert all(point["f1"] <= 0.5 for point in body["equivalent"])
    f2 = [point["f2"] for point in body["equivalent"]]
    assert f2 == sorted(f2)


def test_exports_hold_every_trial(client, keys, finished):
    csv_response = client.get(f"/api/v1/studies/{finished}/export.csv", headers=keys.auth())
    json_response = client.get(f"/api/v1/studies/{finished}/export.json", headers=keys.auth())

    rows = list(csv.DictReader(io.StringIO(csv_response.text)))
    assert csv_response.headers["content-type"].startswith("text/csv")
    assert len(rows) == 12
    assert {"E", "nu", "e", "mu", "engine", "n_remaining [items]", "f1", "f2", "pareto"} <= set(rows[0])
    assert len(json_response.json()["trials"]) == 12
    assert json_response.json()["study"]["id"] == finished


def test_study_progress_counts_done_trials_and_best(client, keys, finished):
    body = client.get(f"/api/v1/studies/{finished}", headers=keys.auth()).json()
    trials = client.get(f"/api/v1/studies/{finished}/trials", headers=keys.auth()).json()["items"]

    assert body["status"] == "done"
    assert body["progress"]["trials_done"] == body["progress"]["trials_total"] == 12
    assert body["best"]["f1"] == min(item["f1"] for item in trials)
    # Initial population + 2 generations, all recorded: generation 2 of 2, in the list too.
    assert (body["progress"]["generation"], body["progress"]["generations_total"]) == (2, 2)
    # The fresh-seed validation comes after the extra replicates' batch (3): the dashboard reads it.
    assert body["progress"]["validation_batch"] == 4
    listed = client.get("/api/v1/studies", headers=keys.auth()).json()["items"]
    assert [(item["generation"], item["generations_total"]) for item in listed] == [(2, 2)]


def test_metrics_count_studies_trials_and_seconds(client, keys, store, finished):
    text = client.get("/metrics", headers=keys.auth()).text

    assert 'demcal_studies{status="done"} 1' in text
    assert 'demcal_trials{state="done"} 12' in text
    assert "demcal_simulation_seconds_total " in text


def test_study_declares_its_responses_with_units_and_trials_carry_them(client, keys, finished):
    body = client.get(f"/api/v1/studies/{finished}", headers=keys.auth()).json()
    assert body["responses"] == [
        {
            "name": "n_remaining",
            "unit": "items",
            "type": "integer",
            "failed_value": body["responses"][0]["failed_value"],
            "description": "N_t: items still in the tray at the end of the vibration.",
            "label": "N_t",
        }
    ]
    assert body["f1_unit"] == "items"
    assert body["f1_rule"] == "|median(n_remaining) - 4|"  # one replicate: the median's distance
    # With replicates, the search's f1 is W1 to the measured values, and the study says so.
    wide = StudyDefinition.model_validate(study_definition(replicates=3))
    assert f1_rule(wide).startswith("W1(n_remaining of the replicates")
    listed = client.get("/api/v1/studies", headers=keys.auth()).json()["items"]
    assert [item["f1_unit"] for item in listed] == ["items"]
    trials = client.get(f"/api/v1/studies/{finished}/trials", headers=keys.auth()).json()["items"]
    done = [item for item in trials if item["status"] == "ok"]
    assert done and all(item["responses"] == {"n_remaining": item["n_remaining"]} for item in done)
    assert all(item["engine"] == "numba" for item in trials)
    summary = client.get(f"/api/v1/studies/{finished}/generations", headers=keys.auth()).json()
    assert set(summary[0]["responses"]) == {"n_remaining"}


def test_a_heap_study_declares_its_angle_with_its_unit(client, keys):
    from tests.api.conftest import study_definition

    definition = study_definition(
        scenario={"kind": "angle_of_repose"}, experiment={"response": "angle_deg", "measured": [30.0, 31.0]}
    )
    created = client.post("/api/v1/studies", json=definition, headers=keys.auth())
    assert created.status_code == 201, created.text
    body = created.json()
    assert [(r["name"], r["unit"], r["type"]) for r in body["responses"]] == [
        ("angle_deg", "deg", "real"),
        ("height", "m", "real"),
    ]
    assert body["definition"]["experiments"][0]["round"] == "none"
    assert body["f1_unit"] == "deg"  # f1 = |angle - target|
    bad = client.post(
        "/api/v1/studies",
        json=study_definition(
            scenario={"kind": "angle_of_repose"}, experiment={"response": "N_t", "measured": [3]}
        ),
        headers=keys.auth(),
    )
    assert bad.status_code == 422 and "no response 'N_t'" in bad.text
    engine = client.post("/api/v1/studies", json=study_definition(engine="liggghts"), headers=keys.auth())
    assert engine.status_code == 422 and "does not run scenario 'feeder'" in engine.text


def test_csv_has_a_column_per_declared_response_headed_with_its_unit(client, keys, store):
    from tests.dashboard.seed import seed_heap_study

    seeded = seed_heap_study(store, with_feeder=True)
    study = client.get(f"/api/v1/studies/{seeded.study_id}", headers=keys.auth()).json()
    response = client.get(f"/api/v1/studies/{seeded.study_id}/export.csv", headers=keys.auth())
    rows = list(csv.DictReader(io.StringIO(response.text)))

    columns = ["heap.angle_deg [deg]", "heap.height [m]", "feeder.n_remaining [items]"]
    header = list(rows[0])
    assert header[header.index("status") + 1 : header.index("status") + 4] == columns
    failed = [row for row in rows if row["trial_id"] in seeded.failed]
    assert failed and all(row["failure"] == "unstable" and not any(row[c] for c in columns) for row in failed)
    measured = [row for row in rows if row["trial_id"] not in seeded.failed]
    assert all(row["failure"] == "" and all(row[c] for c in columns) for row in measured)
    assert {float(row["heap.height [m]"]) for row in measured} == {0.04}
    assert study["f1_unit"] == "1"  # each experiment's distance over its tolerance


def test_a_trial_gives_the_whole_protocols_t_and_cost_that_f2_ranks(client, keys, store):
    # A run that emptied the tray stopped early: f2 is its T x full_load_factor, the whole
    # protocol's (optimizer/objectives.py). The trial lists give that beside the run's own, so
    # that the dashboard draws the points where the search ranked them.
    from optimizer.memory import synthetic_result
    from optimizer.objectives import evaluate, protocol_cost, protocol_wall_time
    from optimizer.protocols import TrialOutcome, TrialSpec, trial_id

    study_id = store.create_study(study_definition(replicates=1), owner="alice")
    params = {"E": 1e7, "nu": 0.3, "e": 0.5, "mu": 0.5}
    specs = [TrialSpec(trial_id(study_id, i, 0), study_id, i, 0, 0, i, params, {}) for i in range(2)]
    store.add_trials(specs)
    result = synthetic_result(specs[0]).model_copy(update={"full_load_factor": 2.5})
    store.record_result(TrialOutcome(specs[0].trial_id, result))
    definition = StudyDefinition.model_validate(store.load_study(study_id).definition)
    (evaluation,) = evaluate(store.trials(study_id), definition, definition.n_items())

    done, pending = client.get(f"/api/v1/studies/{study_id}/trials", headers=keys.auth()).json()["items"]
    one = client.get(f"/api/v1/studies/{study_id}/trials/{specs[0].trial_id}", headers=keys.auth()).json()

    assert done["wall_time_s"] == result.wall_time_s and done["cost"] == result.cost  # the run's own
    assert done["protocol_wall_time_s"] == pytest.approx(protocol_wall_time(result))
    assert done["protocol_cost"] == pytest.approx(protocol_cost(result))
    assert done["protocol_cost"] == pytest.approx(2.5 * result.cost)
    assert done["protocol_cost"] == pytest.approx(evaluation.f2)  # what the search ranked (cost)
    assert {key: one[key] for key in done} == done
    assert pending["protocol_wall_time_s"] is None and pending["protocol_cost"] is None
    (generation,) = client.get(f"/api/v1/studies/{study_id}/generations", headers=keys.auth()).json()
    assert generation["protocol_cost"]["median"] == pytest.approx(2.5 * result.cost)  # Fig. 5's T panel
    assert generation["protocol_wall_time_s"]["median"] == pytest.approx(protocol_wall_time(result))


def test_the_generation_summary_is_built_once_per_change_and_a_poll_without_one_is_a_304(
    client, keys, store, finished
):
    # The dashboard reads it after every change of the trials, for Fig. 5's W1s.
    from dataclasses import replace

    from optimizer.protocols import StudyStatus, trial_id

    url = f"/api/v1/studies/{finished}/generations"
    first = client.get(url, headers=keys.auth())
    again = client.get(url, headers={**keys.auth(), "If-None-Match": first.headers["etag"]})
    store.transition(finished, [StudyStatus.DONE], StudyStatus.DONE)  # a change of the study row

    moved = client.get(url, headers={**keys.auth(), "If-None-Match": first.headers["etag"]})
    template = store.trials(finished)[0].spec
    store.add_trials([replace(template, trial_id=trial_id(finished, 99, 0), individual=99, generation=3)])
    added = client.get(url, headers={**keys.auth(), "If-None-Match": moved.headers["etag"]})

    assert first.status_code == 200 and first.headers["cache-control"] == "no-cache"
    assert again.status_code == 304 and again.content == b""
    assert moved.status_code == 304  # the same bytes under the new version
    assert added.status_code == 200 and [g["trials"] for g in added.json()] == [6, 3, 3, 1]

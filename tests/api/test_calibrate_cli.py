"""``demcal calibrate`` end to end on the embedded default: a SQLite file and the local pool
running real (tiny) feeder simulations; Ctrl-C then ``--resume`` gives an uninterrupted run's
simulations."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import sqlalchemy as sa
from typer.testing import CliRunner

from api.cli import app
from tests.conftest import DETERMINISTIC_RESULT_FIELDS
from tests.worker.test_jobs import TINY_SCENARIO

STUDY = """
name = "tiny"
seed = 5
trial_timeout_s = 120
[scenario.items]
counts = {{ smartphone = 1, camera = 1 }}
resolution = 4
[scenario.stages]
insertion_time = 0.1
vibration_start = 0.3
vibration_time = {vibration_time}
[scenario.run]
dt = 1e-5
[parameters]
E = {{ low = 1e6, high = 3e6 }}
nu = {{ fixed = 0.3 }}
[experiment]
measured = [1, 1, 2]
[ga]
population = {population}
offspring = 2
generations = 1
[validation]
seeds = 0
"""


# Vibration of the studies stopped after their first result: long enough that the signal comes
# while trials remain, with the engine as fast as it is (at 1 s, and once at 10 s in a fresh
# clone with a second study computing alongside, the six trials finished before the signal).
SLOW_VIBRATION_S = 60.0


def write_study(folder: Path, population=2, vibration_time=TINY_SCENARIO["stages"]["vibration_time"]) -> Path:
    path = folder / "study.toml"
    path.write_text(STUDY.format(population=population, vibration_time=vibration_time))
    return path


def demcal(args, folder: Path) -> subprocess.Popen:
    """The installed ``demcal`` on a SQLite file in ``folder``, output captured."""
    env = {
        **os.environ,
        "DEMCAL_DATABASE_URL": f"sqlite:///{folder}/demcal.db",
        "DEMCAL_LOG_LEVEL": "WARNING",
    }
    command = [str(Path(sys.executable).parent / "demcal"), *args]
    return subprocess.Popen(
        command, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def finish(process: subprocess.Popen, timeout: float) -> str:
    """Its output once it exits; on timeout it is killed (with its pool) and the test fails."""
    try:
        output, _ = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGINT)  # the CLI's clean stop also ends its worker processes
        output, _ = process.communicate(timeout=30)
        raise AssertionError(f"demcal did not finish within {timeout:g} s:\n{output}") from None
    return output


def store_for(folder: Path):
    from api.db import create_db_engine
    from api.store import SqlStore

    return SqlStore(create_db_engine(f"sqlite:///{folder}/demcal.db"))


def wait_for_a_result(folder: Path, limit_s: float = 240.0) -> bool:
    """Until a trial has a result; whether a trial was seen running on a local worker before."""
    from optimizer.protocols import StudyStatus, TrialState

    end = time.monotonic() + limit_s
    seen_running = False
    while time.monotonic() < end:
        time.sleep(0.1)
        if not (folder / "demcal.db").exists():
            continue
        try:
            store = store_for(folder)
            running = store.studies_in([StudyStatus.RUNNING])
        except sa.exc.OperationalError:
            continue  # the file exists before the process has migrated it: not ready yet
        for study_id in running:
            records = store.trials(study_id)
            seen_running |= any(
                r.state is TrialState.RUNNING and (r.worker or "").startswith("local-") for r in records
            )
            if any(record.result is not None for record in records):
                return seen_running
    raise AssertionError(f"no simulation finished within {limit_s:g} s")


@pytest.fixture
def embedded(tmp_path, monkeypatch):
    """``demcal`` in this process, on a SQLite file in ``tmp_path``."""
    from api.settings import get_settings

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("DEMCAL_DATABASE_URL", f"sqlite:///{tmp_path}/demcal.db")
    get_settings.cache_clear()
    yield CliRunner()
    get_settings.cache_clear()


def test_bad_study_file_names_the_field(embedded, tmp_path):
    (tmp_path / "study.toml").write_text(
        "[experiment]\nmeasured = [1]\n[parameters.nu]\nlow = 0.4\nhigh = 0.2\n"
    )

    result = embedded.invoke(app, ["calibrate", "study.toml"])

    assert result.exit_code == 2
    assert "scenario" in result.output and "parameters.nu" in result.output


def test_resume_of_an_unknown_study_says_what_to_check(embedded):
    result = embedded.invoke(app, ["calibrate", "--resume", "st-nope"])

    assert result.exit_code == 2
    assert "no study 'st-nope'" in result.output


@pytest.mark.slow
def test_tiny_study_runs_and_writes_its_results(tmp_path):
    write_study(tmp_path)

    process = demcal(["calibrate", "study.toml", "--workers", "2", "--results", "out"], tmp_path)
    output = finish(process, 300)

    assert process.returncode == 0, output
    [folder] = (tmp_path / "out").iterdir()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["status"] == "done" and summary["simulations"] == 2 + 2
    assert len((folder / "trials.csv").read_text().splitlines()) == 1 + 4
    assert (folder / "pareto.png").stat().st_size > 0
    assert "Pareto front" in output
    # Fig. 5 in two lines, from the summary's generations (two batches of one individual each).
    search = [g for g in summary["generations"] if g["individuals"]]
    medians = " ".join(f"{g['n_remaining']['median']:g}" for g in search)
    distances = " ".join(
        f"{g['w1_to_experiment']['n_remaining']:.2f}"
        + ("*" if g["as_experiment"]["n_remaining"]["alike"] else "")
        for g in search
    )
    assert f"per generation: median n_remaining {medians} (target" in output
    assert f"per generation: W1 to the experiment {distances}" in output
    # Every finished trial has its start (a run shorter than a poll, never seen running, has its
    # end less its wall time) and its local worker.
    with sa.create_engine(f"sqlite:///{tmp_path}/demcal.db").connect() as db:
        rows = db.execute(sa.text("SELECT started_at, finished_at, worker FROM trials")).all()
    assert len(rows) == 4
    assert all(started and started <= finished for started, finished, _ in rows), rows
    assert all(worker.startswith("local-") for _, _, worker in rows), rows


def test_a_study_whose_every_run_fails_ends_with_the_failures_and_no_recommendation(tmp_path):
    """Every run ends ``timeout`` (a limit no simulation can meet): the CLI prints the failure
    table and says nothing was measured, exit 0, where its progress line raised a TypeError (no
    hypervolume reference point without a measured run)."""
    path = write_study(tmp_path)
    path.write_text(path.read_text().replace("trial_timeout_s = 120", "trial_timeout_s = 0.001"))

    process = demcal(["calibrate", "study.toml", "--workers", "2", "--results", "out"], tmp_path)
    output = finish(process, 300)

    assert process.returncode == 0, output
    assert "Traceback" not in output
    assert "No simulation measured anything (failed: 4 (timeout 4))" in " ".join(output.split())
    [folder] = (tmp_path / "out").iterdir()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["recommendation"] is None and summary["failures"]["total"] == 4


def by_individual(store, study_id: str) -> dict[tuple[int, int, int], tuple]:
    """A study's trials keyed by (generation, individual, replicate): spec and result."""
    fields = DETERMINISTIC_RESULT_FIELDS
    return {
        (r.spec.generation, r.spec.individual, r.spec.replicate): (
            r.spec.params, r.spec.seed, r.result.model_dump(include=fields) if r.result else None,
        )
        for r in store.trials(study_id)
    }


@pytest.mark.slow
def stopped_after_a_result(folder: Path, sig: int) -> tuple[subprocess.Popen, str, str, bool]:
    """``calibrate study.toml`` in ``folder`` sent ``sig`` once a trial has a result: the process,
    its output, the study id it printed and whether a trial was seen running before."""
    process = demcal(["calibrate", "study.toml", "--workers", "1"], folder)
    try:
        seen_running = wait_for_a_result(folder)
    finally:
        process.send_signal(sig)
    output = finish(process, 60)
    return process, output, next(word for word in output.split() if word.startswith("st-")), seen_running


def test_ctrl_c_then_resume_gives_the_trials_and_results_of_an_uninterrupted_run(tmp_path):
    interrupted_dir, clean_dir = tmp_path / "interrupted", tmp_path / "clean"
    for folder in (interrupted_dir, clean_dir):
        folder.mkdir()
        write_study(folder, population=4, vibration_time=SLOW_VIBRATION_S)
    clean = demcal(["calibrate", "study.toml", "--workers", "1"], clean_dir)  # alongside, same seed
    process, output, study_id, _ = stopped_after_a_result(interrupted_dir, signal.SIGINT)
    store = store_for(interrupted_dir)
    kept = {r.spec.trial_id: r.result for r in store.trials(study_id) if r.result is not None}
    resumed = demcal(["calibrate", "--resume", study_id, "--workers", "2"], interrupted_dir)
    resumed_output = finish(resumed, 300)
    clean_output = finish(clean, 300)
    clean_id = next(word for word in clean_output.split() if word.startswith("st-"))

    trials = {r.spec.trial_id: r.result for r in store.trials(study_id)}
    assert process.returncode == 130, output
    assert f"demcal calibrate --resume {study_id}" in output
    assert resumed.returncode == 0, resumed_output
    assert clean.returncode == 0, clean_output
    assert 0 < len(kept) < 4 + 2
    assert f"{len(kept)} simulations already done are kept" in resumed_output
    assert len(trials) == 4 + 2 and all(result is not None for result in trials.values())
    assert {tid: trials[tid] for tid in kept} == kept
    # The same trials (generation, individual, parameters, seed) with the same results as the
    # run nobody interrupted.
    assert by_individual(store, study_id) == by_individual(store_for(clean_dir), clean_id)




def test_sigterm_pauses_the_study_and_frees_it_so_no_serve_takes_it_over(tmp_path):
    from api.store.leases import DatabaseLeases
    from optimizer.protocols import StudyStatus

    write_study(tmp_path, population=4, vibration_time=SLOW_VIBRATION_S)
    process, output, study_id, seen_running = stopped_after_a_result(tmp_path, signal.SIGTERM)
    store = store_for(tmp_path)

    # What `studies show`, the API and the dashboard see of a CLI study: the trial a local worker
    # took shows running, on that worker (it showed queued until its result before).
    assert seen_running
    study = store.load_study(study_id)
    assert process.returncode == 130, output
    assert study.status is StudyStatus.PAUSED  # a serve scans active studies only: not this one
    assert f"demcal calibrate --resume {study_id}" in study.message
    assert DatabaseLeases(store, "serve-elsewhere").acquire(study_id)  # the lease was released


def test_validation_seeds_beyond_the_budget_exit_2_saying_what_fits(embedded, tmp_path):
    (tmp_path / "study.toml").write_text(
        "budget = 200\n[scenario]\n[experiment]\nmeasured = [1]\n[validation]\nseeds = 20\n"
    )

    result = embedded.invoke(app, ["calibrate", "study.toml"])

    assert result.exit_code == 2
    assert "validation.seeds <= 5" in result.output


@pytest.mark.parametrize(
    ("overrides", "rule"),
    [
        ({"replicates": 3}, "f1 = W1(n_remaining of the replicates, 10 measured values)"),
        ({"replicates": 1}, "f1 = |median(n_remaining) - 4|"),
    ],
)
def test_the_pareto_table_title_gives_the_study_s_own_f1(tmp_path, overrides, rule):
    """With 3 replicates f1 is the Wasserstein-1 distance: a title saying |N_t - target| would
    describe a different objective from the one the table ranks by."""
    from rich.console import Console

    from api.commands.calibrate import _report
    from optimizer.driver import Driver
    from optimizer.memory import MemoryStore, SyntheticExecutor, synthetic_result
    from tests.optimizer.conftest import make_definition

    definition = make_definition(
        ga={"population": 4, "offspring": 2, "generations": 1}, validation={"seeds": 0}, **overrides
    )
    store = MemoryStore()
    study_id = store.create_study(definition.model_dump(mode="json"))
    Driver(store, SyntheticExecutor(synthetic_result)).run_to_completion(study_id, poll_timeout=0)
    console = Console(record=True, width=200)

    _report(console, store, study_id, tmp_path)

    cli = console.export_text()
    assert f"Pareto front of {study_id} ({rule})" in cli
    summary = json.loads(next(tmp_path.glob("*/summary.json")).read_text())
    assert summary["f1_rule"] == rule.removeprefix("f1 = ")


def test_a_bad_scenario_in_a_study_file_exits_2_naming_the_field_of_its_kind(embedded, tmp_path):
    (tmp_path / "study.toml").write_text(
        '[scenario]\nkind = "angle_of_repose"\n[scenario.cylinder]\nheight = -1\n'
        "[experiment]\nmeasured = [30]\n"
    )

    result = embedded.invoke(app, ["calibrate", "study.toml"])

    assert result.exit_code == 2
    assert "scenario.cylinder.height: Input should be greater than 0" in result.output


def test_a_validation_table_written_to_a_log_keeps_its_verdicts_whole(monkeypatch, capsys):
    """Piped or logged, rich drew 80 columns and the paper study's table read 'vali…'."""
    row = {
        "params": {"E": 9.67e6, "nu": 0.363, "e": 0.175, "mu": 0.914}, "search_f1": 0.0,
        "n_remaining": [0, 0, 10, 4, 9, 3, 1, 15, 16, 3], "failures": [], "median": 3.5,
        "median_interval": [1.5, 10.0], "w1": 0.8, "f1": 0.5, "f1_interval": [0.0, 6.0],
    }  # fmt: skip
    output = _printed_validation_table(monkeypatch, capsys, [
        dict(row, individual=77, verdict="validated"),
        dict(row, individual=152, verdict="not reproduced", failures=["unstable"]),
    ])  # fmt: skip

    assert "…" not in output
    assert "validated" in output and "not reproduced" in output and "+1 failed" in output
    assert "0,0,10,4,9,3,1,15,16,3" in output


def test_a_validation_table_of_a_pooled_search_shows_the_pooled_w1_its_candidates_were_chosen_on(
    monkeypatch, capsys
):
    """Calibration 18's #76: own run 9 (search f1 5), pooled W1 2.89 within the floor (starred)."""
    row = {
        "params": {"E": 1.67e8, "nu": 0.44, "e": 0.22, "mu": 0.84}, "search_f1": 5.0,
        "search_pooled_w1": 2.89, "search_pooled_violation": -0.21,
        "n_remaining": [6, 4, 0, 0, 0, 11, 0, 13, 7, 3], "failures": [], "median": 3.5,
        "median_interval": [0.0, 7.0], "w1": 1.7, "f1": 0.5, "f1_interval": [0.0, 4.0],
    }  # fmt: skip
    output = _printed_validation_table(monkeypatch, capsys, [
        dict(row, individual=76, verdict="validated"),
        dict(row, individual=178, verdict="validated", search_f1=0.0, search_pooled_w1=1.43,
             search_pooled_violation=0.09),
    ])  # fmt: skip

    assert "pooled W1" in output and "2.89*" in output and "1.43 " in output and "1.43*" not in output
    assert "Recommendation: validated (the fastest validated set)." in output


def _printed_validation_table(monkeypatch, capsys, rows: list[dict]) -> str:
    """The CLI's validation table of a validated study with ``rows``, as a log would keep it."""
    from api.commands.calibrate import _validation_table
    from api.commands.console import cli_console

    monkeypatch.delenv("COLUMNS", raising=False)
    summary = {
        "measured": [0, 0, 1, 2, 3, 4, 4, 12, 15, 16], "responses_measured": "N_t",
        "validation_status": "validated", "validation": rows,
    }  # fmt: skip
    _validation_table(cli_console(), summary)
    return capsys.readouterr().out

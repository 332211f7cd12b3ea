"""``demcal calibrate``: run a whole calibration study on this machine, the embedded default.

The study is stored in the same database ``demcal serve`` uses (``DEMCAL_DATABASE_URL``, a SQLite
file by default), so the service and its dashboard show it; simulations run on a local process
pool (``--workers``, default ``DEMCAL_WORKERS``, 0 = one per core). While it runs, a live line
shows the batch, trials done and running, the ETA and the best f1 so far; at the end it prints
the Pareto front and the recommendation and writes ``<results>/<name>-<study id>/`` with
``trials.csv``, ``summary.json`` and ``pareto.png``.

Ctrl-C (or SIGTERM) stops the pool and leaves the study paused with every finished trial kept;
``--resume STUDY_ID`` continues it without re-running anything that finished, so the study ends
with the same simulations as an uninterrupted run.

One driver per study: ``calibrate`` takes the study's lease in the database, the one
``demcal serve`` takes (``api/store/leases.py``), and renews it while it runs. ``--resume`` of a
study another live process drives is refused (exit 2, naming it); a ``calibrate`` killed without
a chance to pause loses the study to a ``serve`` replica once its lease expires.

This module composes (settings, store, pool, driver) and reports; study logic lives in
``optimizer/``.
"""

from __future__ import annotations

import logging
import math
import signal
import time
from pathlib import Path

import typer

from api.commands.console import cli_console
from dem.parameters import item_parameter

logger = logging.getLogger(__name__)

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


class LeaseLost(RuntimeError):
    """Another process holds the study's lease now; this one must stop driving it."""


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", err=True, fg="red")
    raise typer.Exit(EXIT_USER_ERROR)


def register(app: typer.Typer) -> None:
    @app.command("calibrate")
    def calibrate(
        study_file: Path | None = typer.Argument(
            None, help="Study definition (.toml or .json); not needed with --resume."
        ),
        workers: int | None = typer.Option(
            None, "--workers", "-w", min=0, help="Local worker processes (0 = one per core)."
        ),
        resume: str | None = typer.Option(
            None, "--resume", help="Continue this stored study (its id) instead of starting one."
        ),
        results: Path = typer.Option(Path("results"), "--results", help="Where the results folder goes."),
    ) -> None:
        """Calibrate E, nu, e, mu against an experiment with a multi-objective GA, locally."""
        from api.settings import get_settings

        settings = get_settings()
        definition = None if resume else _load(study_file)
        store = _open_store(settings.database_url)
        from api.store.leases import DatabaseLeases

        leases = DatabaseLeases(store, ttl_s=settings.lease_ttl_s)
        study_id = _resume(store, resume, leases) if resume else _create(store, definition, leases)
        try:
            _run(store, study_id, workers if workers is not None else settings.workers, results, leases)
        finally:
            leases.release(study_id)


def _open_store(database_url: str):
    from api.db import create_db_engine, upgrade_database
    from api.store import SqlStore

    # The embedded mode owns its database: bring the schema up to date like `demcal db upgrade`.
    upgrade_database(database_url)
    return SqlStore(create_db_engine(database_url))


def _load(study_file: Path | None):
    from optimizer.study import StudyDefinitionError, load_study_file

    if study_file is None:
        _fail("give a study file (e.g. examples/study-quick.toml) or --resume STUDY_ID")
    try:
        return load_study_file(study_file)
    except StudyDefinitionError as exc:
        _fail(str(exc))


def _create(store, definition, leases) -> str:
    from api.services.studies import study_warnings

    experiments = definition.experiments
    warnings = study_warnings(definition)
    study_id = store.create_study(definition.model_dump(mode="json"), None, warnings=warnings)
    if not leases.acquire(study_id):  # a serve replica scanned in between: let it drive
        _fail(f"study {study_id} was taken by `demcal serve` at once; follow it on the dashboard")
    typer.echo(
        f"study {study_id} ({definition.name}): up to {definition.total_simulations()} simulations, "
        f"engine {definition.engine}, "
        + "; ".join(f"target {x.response} = {x.target():g} +- {x.tolerance:g}" for x in experiments)
        + f"; match: f1 ({definition.experiment.distance}) <= {definition.match_tolerance():g}, "
        f"{definition.replicates} replicate(s) on common seeds, validation on "
        f"{definition.validation.seeds} fresh seeds"
    )
    for warning in warnings:
        typer.secho(f"warning: {warning}", err=True, fg="yellow")
    return study_id


def _resume(store, study_id: str, leases) -> str:
    from api.errors import NotFoundError
    from optimizer.protocols import FINISHED_STUDIES, StudyStatus

    try:
        study = store.load_study(study_id)
    except NotFoundError:
        _fail(f"no study {study_id!r} in this database; check DEMCAL_DATABASE_URL and the id")
    if study.status in FINISHED_STUDIES:
        _fail(f"study {study_id} is {study.status.value}; only a paused or running study can be resumed")
    if not leases.acquire(study_id):
        holder, until = leases.holder(study_id) or ("another process", None)
        _fail(
            f"study {study_id} is being driven by {holder} (its lease holds until {until:%H:%M:%S} "
            "UTC and is renewed while it runs); pause it there, or let that process finish it"
            if until else f"study {study_id} is being driven by another process"
        )
    done = sum(record.result is not None for record in store.trials(study_id))
    store.set_status(study_id, StudyStatus.RUNNING, "resumed from the command line")
    typer.echo(f"resuming study {study_id}: {done} simulations already done are kept")
    return study_id


def _run(store, study_id: str, workers: int, results: Path, leases) -> None:

    from api.driver_loop import RunningMarks
    from api.settings import get_settings
    from optimizer.driver import Driver
    from optimizer.protocols import StudyStatus
    from worker.local import LocalPoolExecutor

    console = cli_console()
    settings = get_settings()
    executor = LocalPoolExecutor(workers, snapshot_root=settings.snapshot_root, nice=settings.worker_nice)
    driver = Driver(store, executor)
    renewed = time.monotonic()
    marks = RunningMarks()  # what `demcal studies show`, the API and the dashboard see running

    def on_progress(progress) -> None:
        nonlocal renewed
        live.update(progress)
        marks.update(store, executor)
        if time.monotonic() - renewed >= leases.renew_every_s:
            renewed = time.monotonic()
            if not leases.renew(study_id):
                raise LeaseLost(study_id)

    # SIGTERM stops the run like Ctrl-C: the study is paused and the lease released, so no other
    # process silently takes over a study its user stopped.
    signal.signal(signal.SIGTERM, _interrupt)
    # Ctrl-C, or `kill -INT` of a run started in the background: a shell without job control
    # starts background commands with SIGINT ignored, and Python then keeps ignoring it.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with _LiveProgress(console, executor) as live:
            final = driver.run_to_completion(study_id, on_progress=on_progress)
    except LeaseLost:
        executor.close()
        _fail(f"study {study_id} was taken over by another process (its lease expired while this one hung)")
    except KeyboardInterrupt:
        executor.close()
        message = f"interrupted; resume with: demcal calibrate --resume {study_id}"
        store.set_status(study_id, StudyStatus.PAUSED, message)
        console.print(f"[yellow]stopped.[/] Finished simulations are kept; {message}", soft_wrap=True)
        raise typer.Exit(EXIT_INTERRUPTED) from None
    executor.close()
    if final.status is not StudyStatus.DONE:
        console.print(f"study {study_id} is {final.status.value}: {final.message}")
        raise typer.Exit(1)
    _report(console, store, study_id, results)


class _LiveProgress:
    """One rich progress bar over the study's simulations, with the batch and the best f1."""

    def __init__(self, console, executor):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.executor = executor
        self.progress = Progress(
            TextColumn("{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("running {task.fields[running]}"),
            TextColumn("best f1 {task.fields[best]}"),
            TimeElapsedColumn(),
            TextColumn("ETA"),
            TimeRemainingColumn(),
            console=console,
        )
        self.task = None

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc_info):
        return self.progress.__exit__(*exc_info)

    def update(self, progress) -> None:
        best = "-" if progress.best_f1 is None else f"{progress.best_f1:g}"
        batch = min(progress.batch + 1, progress.batches)
        label = "initial population" if progress.batch == 0 else f"generation {progress.batch}"
        if progress.batch >= progress.batches:
            label = "done"
        description = f"batch {batch}/{progress.batches} ({label})"
        fields = dict(running=len(self.executor.running()), best=best)
        if self.task is None:
            self.task = self.progress.add_task(description, total=progress.trials_planned, **fields)
        self.progress.update(
            self.task,
            description=description,
            completed=progress.trials_done,
            total=max(progress.trials_planned, progress.trials_done),
            **fields,
        )


def _report(console, store, study_id: str, results: Path) -> None:
    from rich.table import Table

    from optimizer.report import study_parameter_names, write_results

    study = store.load_study(study_id)
    records = store.trials(study_id)
    folder = results / f"{study.definition.get('name', 'study')}-{study_id}"
    summary = write_results(folder, study, records)

    experiments = study.definition.get("experiments") or [study.definition.get("experiment") or {}]
    response = experiments[0].get("response") or "n_remaining"
    table = Table(title=f"Pareto front of {study_id} (f1 = {summary['f1_rule']})")
    names = study_parameter_names(study.definition)
    for column in (
        "individual",
        "gen",
        *(_parameter_header(name) for name in names),
        "runs",
        response,
        "f1 [90 %]",
        f"f2 ({summary['objective_time']})",
    ):
        table.add_column(column, justify="right")
    chosen = (summary["recommendation"] or {}).get("individual")
    for member in summary["pareto"]:
        params = member["params"]
        table.add_row(
            f"{member['individual']}{' *' if member['individual'] == chosen else ''}",
            str(member["generation"]),
            *(_parameter_cell(name, params) for name in names),
            str(len(member["trial_ids"])),
            _n_t(member),
            _f1(member),
            _figure(member["f2"]),
        )
    console.print(table)
    _report_failures(console, summary["failures"], summary.get("responses_measured", "N_t"))
    recommendation = summary["recommendation"]
    if recommendation is None and summary["failures"]["total"] == summary["simulations"]:
        console.print(
            f"[yellow]No simulation measured anything[/] ({summary['failures']['text']}): nothing to "
            "recommend; the table of failures above says what to change."
        )
    elif recommendation is None:
        console.print(
            f"[yellow]No parameter set reproduced the experiments (f1 within {summary['tolerance']:g})[/] "
            f"(best f1 {summary['best_f1']}); widen the bounds, add generations or replicates."
        )
    else:
        params = ", ".join(f"{name} = {value:.4g}" for name, value in recommendation["params"].items())
        validated = summary.get("validation_status") == "validated"
        fallback = "the fastest validated set" if validated else "the fastest match"  # older studies
        chosen = recommendation.get("chosen_by") or fallback
        console.print(
            f"[bold green]Recommended[/] (individual {recommendation['individual']}, {chosen}): "
            f"{params}; "
            f"{response} {recommendation['n_remaining']}, {recommendation['wall_time_s']:.1f} s wall "
            "for the whole protocol"
        )
        for other in summary["equivalent"]:
            params = ", ".join(f"{name} = {value:.4g}" for name, value in other["params"].items())
            console.print(
                f"  equivalent (individual {other['individual']}): {params}; f2 {_figure(other['f2'])}"
            )
    _generations_line(console, summary, response)
    _report_progress(console, summary["progress"], summary["identifiability"])
    _validation_table(console, summary)
    first = summary["simulations_until_first_match"]
    matched = f"first match after {first}" if first is not None else "no match"
    console.print(
        f"{summary['simulations']} simulations ({summary['failures']['text']}); {matched}. "
        f"Results in {folder}/"
    )


def _generations_line(console, summary: dict, response: str) -> None:
    """The paper's Fig. 5 in two lines: the median of each generation's measured runs, and how
    far the generation's runs lie from the experiment (W1), which the median alone hides."""
    rows = [entry for entry in summary["generations"] if entry.get("individuals")]
    if not rows:
        return
    medians = " ".join(
        "-" if entry["n_remaining"] is None else f"{entry['n_remaining']['median']:g}" for entry in rows
    )
    distances = " ".join(_w1_text(entry, response) for entry in rows)
    target = f"target {summary['target']:g}"
    console.print(f"per generation: median {response} {medians} ({target})", soft_wrap=True)
    console.print(
        f"per generation: W1 to the experiment {distances} (* below the 95 % point of the experiment's "
        "own resamples of as many runs: behaves as the experiment)",
        soft_wrap=True,
    )


def _w1_text(entry: dict, response: str) -> str:
    w1 = (entry.get("w1_to_experiment") or {}).get(response)
    if w1 is None:
        return "-"
    band = (entry.get("as_experiment") or {}).get(response)
    return f"{w1:.2f}" + ("*" if band and band["alike"] else "")


def _n_t(member: dict) -> str:
    """N_t of a listed individual; a failed one shows how it failed, never a count."""
    if member.get("failure"):
        return f"[red]{member['failure'].split(':', 1)[0]}[/]"
    return ",".join(str(n) for n in member["n_remaining"])


def _f1(member: dict) -> str:
    """f1 with its bootstrap interval over the replicates, where the summary carries one."""
    interval = member.get("f1_interval")
    if not interval or interval[0] == interval[1]:
        return f"{member['f1']:g}"
    return f"{member['f1']:.3g} [{interval[0]:.2g}-{interval[1]:.2g}]"


def _report_failures(console, failures: dict, measured: str) -> None:
    """The runs that measured nothing, apart from the front: one row per status with its count
    and the first such run's message (what to change)."""
    if not failures["total"]:
        console.print(f"failed: 0 (every simulation measured {measured})")
        return
    from rich.table import Table

    table = Table(title=failures["text"] + f": not ranked, no {measured}", title_justify="left")
    table.add_column("status")
    table.add_column("runs", justify="right")
    table.add_column("first message", overflow="fold")
    for status, count in failures["by_status"].items():
        table.add_row(status, str(count), failures["first_message"].get(status, ""))
    console.print(table)


def _report_progress(console, progress: dict, identified: dict) -> None:
    """Where the search got to (hypervolume, best f1, best validated f1 at the last batch) and
    which parameters the experiment pins down."""
    if progress["points"]:
        last, reference = progress["points"][-1], progress["reference"]
        hv = "-" if last["hypervolume"] is None else f"{last['hypervolume']:.3f}"
        validated = last["best_validated_f1"]
        box = (
            "no reference point: no run of the first batch measured"
            if reference is None
            else f"reference f1 = {reference['f1']:g}, f2 = {reference['f2']:.3g}"
        )
        console.print(
            f"progress after {last['simulations']} simulations: hypervolume {hv} ({box}), "
            f"best f1 {_optional(last['best_f1'])}, best validated f1 {_optional(validated)}",
            soft_wrap=True,
        )
    if identified["parameters"]:
        verdicts = ", ".join(
            f"{entry['name']} {'pinned together' if entry.get('pinned_together') else entry['verdict']} "
            f"(total index {entry['total']:.2f}"
            + _spread_text(entry["matching_spread"])
            + ")"
            for entry in identified["parameters"]
        )
        console.print(f"identifiability: {verdicts}", soft_wrap=True)
        alone = [entry for entry in identified.get("experiments", []) if entry["parameters"]]
        for entry in alone if len(alone) > 1 else []:
            own = ", ".join(f"{row['name']} {row['verdict']}" for row in entry["parameters"])
            console.print(f"  {entry['response']} alone: {own}", soft_wrap=True)
    else:
        console.print(f"identifiability: {identified.get('reason') or 'not available'}", soft_wrap=True)


def _spread_text(spread: float | None) -> str:
    return "" if spread is None else f", matching spread {spread:.2f}"


def _optional(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


def _parameter_header(name: str) -> str:
    """A parameter's column: a modulus with its unit ('E [Pa]', 'E_wall [Pa]')."""
    return f"{name} [Pa]" if item_parameter(name) == "E" else name


def _parameter_cell(name: str, params: dict) -> str:
    value = params.get(name)
    if value is None:
        return "-"
    return f"{value:.3g}" if item_parameter(name) == "E" else f"{value:.3f}"


def _validation_table(console, summary: dict) -> None:
    """The end of every study: each candidate's fresh-seed N_t against the experiment."""
    from rich.table import Table

    rows = summary.get("validation") or []
    if not rows:
        if summary.get("validation_status"):
            console.print(f"Recommendation {summary['validation_status']}.")
        return
    measured, response = summary["measured"], summary.get("responses_measured", "N_t")
    table = Table(
        title=f"Validation on fresh seeds (experiment: median {_median(measured):g}, {response} {measured})"
    )
    # nu and nu_wall hardly matter: kept narrow
    names = [name for name in rows[0]["params"] if item_parameter(name) != "nu"]
    # A GA ranked on pooled neighbours chose its candidates on their pooled W1 (optimizer/validation.py)
    pooled = any(row.get("search_pooled_w1") is not None for row in rows)
    for column in ("individual", *(_parameter_header(name) for name in names), "search f1",
                   *(["pooled W1"] if pooled else []), f"fresh {response}", "median [90 %]", "W1",
                   "f1 [90 %]", "verdict"):  # fmt: skip
        table.add_column(column, justify="right")
    for row in rows:
        params = row["params"]
        median = "-" if row["median"] is None else f"{row['median']:g} [{_span(row['median_interval'])}]"
        f1 = "-" if row["f1"] is None else f"{row['f1']:.2f} [{_span(row['f1_interval'])}]"
        fresh = ",".join(str(n) for n in row["n_remaining"]) + (
            f" +{len(row['failures'])} failed" if row["failures"] else ""
        )
        colour = "green" if row["verdict"] == "validated" else "red"
        table.add_row(
            str(row["individual"]), *(_parameter_cell(name, params) for name in names),
            f"{row['search_f1']:.2f}", *([_pooled(row)] if pooled else []), fresh, median,
            "-" if row["w1"] is None else f"{row['w1']:.2f}",
            f1, f"[{colour}]{row['verdict']}[/]",
        )  # fmt: skip
    console.print(table)
    if pooled:
        console.print(
            "pooled W1: each candidate's search runs pooled with its neighbours' (ga.match_estimate), "
            "which chose the candidates; * within the experiment's noise floor (several experiments: "
            "the largest W1 / floor)."
        )
    status = summary["validation_status"]
    chosen = summary.get("chosen_by") or ("the fastest validated set" if status == "validated" else "")
    console.print(f"Recommendation: {status}" + (f" ({chosen})." if chosen else "."))


def _pooled(row: dict) -> str:
    """The search's pooled W1 of a candidate, starred when that estimate called it feasible."""
    if row.get("search_pooled_w1") is None:
        return "-"
    return f"{row['search_pooled_w1']:.2f}" + ("*" if row["search_pooled_violation"] <= 0 else "")


def _median(values: list[float]) -> float:
    import statistics

    return statistics.median(values)


def _span(interval) -> str:
    return "-" if interval is None else f"{interval[0]:.2g}-{interval[1]:.2g}"


def _figure(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else str(value)

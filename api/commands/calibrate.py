"""``demcal calibrate``: run a whole calibration study on this machine, the embedded default.

The study is stored in the same database ``demcal serve`` uses (``DEMCAL_DATABASE_URL``, a SQLite
file by default), so the service and its dashboard show it; simulations run on a local process
pool (``--workers``, default ``DEMCAL_WORKERS``, 0 = one per core). While it runs, a live line
shows the batch, trials done and running, the ETA and the best f1 so far; at the end it prints
the Pareto front and the recommendation and writes ``<results>/<name>-<study id>/`` with
``trials.csv``, ``summary.json`` and ``pareto.png``.

Ctrl-C stops the pool and leaves the study paused with every finished trial kept;
``--resume STUDY_ID`` continues it without re-running anything that finished, so the study ends
with the same simulations as an uninterrupted run.

This module composes (settings, store, pool, driver) and reports; study logic lives in
``optimizer/``.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import typer

logger = logging.getLogger(__name__)

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


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
        study_id = _resume(store, resume) if resume else _create(store, definition)
        _run(store, study_id, workers if workers is not None else settings.workers, results)


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


def _create(store, definition) -> str:
    study_id = store.create_study(definition.model_dump(mode="json"), None)
    typer.echo(
        f"study {study_id} ({definition.name}): up to {definition.total_simulations()} simulations, "
        f"target N_t = {definition.experiment.target():g} +- {definition.experiment.tolerance:g}"
    )
    return study_id


def _resume(store, study_id: str) -> str:
    from api.errors import NotFoundError
    from optimizer.protocols import StudyStatus

    try:
        study = store.load_study(study_id)
    except NotFoundError:
        _fail(f"no study {study_id!r} in this database; check DEMCAL_DATABASE_URL and the id")
    if study.status in (StudyStatus.DONE, StudyStatus.CANCELLED, StudyStatus.FAILED):
        _fail(f"study {study_id} is {study.status.value}; only a paused or running study can be resumed")
    done = sum(record.result is not None for record in store.trials(study_id))
    store.set_status(study_id, StudyStatus.RUNNING, "resumed from the command line")
    typer.echo(f"resuming study {study_id}: {done} simulations already done are kept")
    return study_id


def _run(store, study_id: str, workers: int, results: Path) -> None:
    from rich.console import Console

    from api.settings import get_settings
    from optimizer.driver import Driver
    from optimizer.protocols import StudyStatus
    from worker.local import LocalPoolExecutor

    console = Console()
    executor = LocalPoolExecutor(workers, snapshot_root=get_settings().data_dir / "snapshots")
    driver = Driver(store, executor)
    try:
        with _LiveProgress(console, executor) as live:
            final = driver.run_to_completion(study_id, on_progress=live.update)
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

    from optimizer.report import write_results

    study = store.load_study(study_id)
    records = store.trials(study_id)
    folder = results / f"{study.definition.get('name', 'study')}-{study_id}"
    summary = write_results(folder, study, records)

    table = Table(title=f"Pareto front of {study_id} (f1 = |N_t - {summary['target']:g}|)")
    for column in (
        "individual",
        "gen",
        "E [Pa]",
        "nu",
        "e",
        "mu",
        "N_t",
        "f1",
        f"f2 ({summary['objective_time']})",
    ):
        table.add_column(column, justify="right")
    chosen = (summary["recommendation"] or {}).get("individual")
    for member in summary["pareto"]:
        params = member["params"]
        table.add_row(
            f"{member['individual']}{' *' if member['individual'] == chosen else ''}",
            str(member["generation"]),
            f"{params['E']:.3g}",
            f"{params['nu']:.3f}",
            f"{params['e']:.3f}",
            f"{params['mu']:.3f}",
            ",".join(str(n) for n in member["n_remaining"]),
            f"{member['f1']:g}",
            _figure(member["f2"]),
        )
    console.print(table)
    recommendation = summary["recommendation"]
    if recommendation is None:
        console.print(
            f"[yellow]No parameter set reproduced N_t within +-{summary['tolerance']:g}[/] "
            f"(best f1 {summary['best_f1']}); widen the bounds, add generations or replicates."
        )
    else:
        params = ", ".join(f"{name} = {value:.4g}" for name, value in recommendation["params"].items())
        console.print(
            f"[bold green]Recommended[/] (individual {recommendation['individual']}, fastest match): "
            f"{params}; "
            f"N_t {recommendation['n_remaining']}, {recommendation['wall_time_s']:.1f} s wall"
        )
        for other in summary["equivalent"]:
            params = ", ".join(f"{name} = {value:.4g}" for name, value in other["params"].items())
            console.print(
                f"  equivalent (individual {other['individual']}): {params}; f2 {_figure(other['f2'])}"
            )
    first = summary["simulations_until_first_match"]
    matched = f"first match after {first}" if first is not None else "no match"
    console.print(f"{summary['simulations']} simulations; {matched}. Results in {folder}/")


def _figure(value: float) -> str:
    return f"{value:.3g}" if math.isfinite(value) else str(value)

"""``demcal worker``: run DEM trials from the Redis queue, on this machine, until stopped.

Start as many as the machine has cores to spare (each runs one simulation at a time, on one
core). Workers need only ``DEMCAL_REDIS_URL``; they never open the database.
"""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    @app.command("worker")
    def worker(
        queues: list[str] = typer.Option(
            None,
            "--queues",
            "-q",
            help="Queues to take trials from, highest priority first (default: DEMCAL_QUEUE_NAME and "
            "DEMCAL_QUEUE_NAME.<engine> for every engine installed here, e.g. .liggghts).",
        ),
        burst: bool = typer.Option(False, "--burst", help="Exit when the queues are empty."),
        max_jobs: int = typer.Option(
            None, "--max-jobs", min=1, help="Exit 0 after this many trials (to recycle workers)."
        ),
        name: str = typer.Option(None, "--name", help="Worker name (default: host.pid.tag)."),
        heartbeat: int = typer.Option(
            10,
            "--heartbeat",
            min=1,
            max=300,
            help="Seconds between heartbeats while a trial runs; a worker silent for 3 heartbeats "
            "is presumed dead and its trial runs again elsewhere.",
        ),
    ) -> None:
        """Run trials from the queue. SIGTERM finishes the current trial, then exits 0; a second
        SIGTERM abandons it (the service runs it again) and exits 1."""
        from api.settings import get_settings
        from dem.engines.base import available_engines
        from worker.rq_executor import engine_queues
        from worker.runner import COLD_STOP_EXIT_CODE, ColdStop, WorkerSetupError, run_worker

        settings = get_settings()
        engines = available_engines()
        typer.echo(f"engines here: {', '.join(engines)}", err=True)
        try:
            run_worker(
                settings.redis_url,
                queues or engine_queues(settings.queue_name, engines),
                burst=burst,
                max_jobs=max_jobs,
                name=name,
                heartbeat_s=heartbeat,
                log_level=settings.log_level,
                snapshot_root=settings.snapshot_root,
                data_dir=settings.data_dir,
                nice=settings.worker_nice,
            )
        except WorkerSetupError as exc:
            typer.secho(f"error: {exc}", err=True, fg="red")
            raise typer.Exit(2) from None
        except ColdStop as exc:
            typer.secho(f"stopped: {exc}", err=True, fg="yellow")
            raise typer.Exit(COLD_STOP_EXIT_CODE) from None

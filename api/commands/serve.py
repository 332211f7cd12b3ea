"""``demcal serve``: the REST API, the dashboard and the study driver in one process.

The driver runs in a background thread (``api/driver_loop.py``) on the RQ queue when
``DEMCAL_REDIS_URL`` is set (trials run on ``demcal worker`` processes), otherwise on a local
process pool. SIGTERM or Ctrl-C stops the server, lets the driver finish its current step and
releases its studies' leases, so another replica can take them over at once.
"""

from __future__ import annotations

import signal

import typer


def _exit_cleanly(signum, frame) -> None:
    raise SystemExit(0)


def register(app: typer.Typer) -> None:
    @app.command("serve")
    def serve(
        host: str = typer.Option(None, "--host", help="Address to bind (default: DEMCAL_HOST)."),
        port: int = typer.Option(None, "--port", min=1, max=65535, help="Port (default: DEMCAL_PORT)."),
        driver: bool = typer.Option(
            True, "--driver/--no-driver", help="Advance studies in this process (off: API only)."
        ),
    ) -> None:
        """Serve the API and dashboard, and drive running studies in the background."""
        import uvicorn

        from api.app import create_app
        from api.db import SchemaOutOfDateError
        from api.driver_loop import build_driver_loop
        from api.settings import get_settings
        from worker.rq_executor import RedisQueueError

        settings = get_settings()
        try:
            application = create_app(settings)
            service = build_driver_loop(settings, application.state.store) if driver else None
        except (SchemaOutOfDateError, RedisQueueError) as exc:
            typer.secho(f"error: {exc}", err=True, fg="red")
            raise typer.Exit(2) from None
        if service is not None:
            service.start()
        # uvicorn catches SIGTERM, shuts the server down, then raises the signal again with the
        # handler it found: with the default one the process would die on the spot, before the
        # ``finally`` below stops the driver and its local worker processes (which then kept
        # computing as orphans). This handler turns that second delivery into a normal exit.
        signal.signal(signal.SIGTERM, _exit_cleanly)
        try:
            uvicorn.run(
                application,
                host=host or settings.host,
                port=port or settings.port,
                log_config=None,  # keep demcal's one-line log format
                log_level=settings.log_level.lower(),
                access_log=settings.log_level == "DEBUG",  # one line per request only when asked
                timeout_graceful_shutdown=10,
            )
        finally:
            if service is not None:
                service.stop()

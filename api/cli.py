"""The ``demcal`` command: one entry point whose subcommands live in ``api/commands/``.

Each command module exposes ``register(app)``; heavy imports (numba, SQLAlchemy) happen inside
the commands so that ``demcal --help`` stays instant.
"""

from __future__ import annotations

import importlib
import sys

import typer

from api import __version__
from api.log import configure_logging
from api.settings import SettingsError, get_settings

COMMAND_MODULES = (
    "api.commands.config",
    "api.commands.db",
    "api.commands.apikey",
    "api.commands.worker",
    "api.commands.serve",
    "api.commands.calibrate",
    "api.commands.simulate",
    "api.commands.render",
    "api.commands.studies",
)

app = typer.Typer(
    name="demcal",
    help="Calibrate DEM contact parameters (E, nu, e, mu) against an experiment with a "
    "multi-objective genetic algorithm.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"demcal {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Read settings once, so that a bad DEMCAL_* variable fails before any work starts."""
    configure_logging(get_settings().log_level)


for _module in COMMAND_MODULES:
    importlib.import_module(_module).register(app)


def main() -> None:
    """Console-script entry point: user errors become a one-line message and exit status 2."""
    try:
        app()
    except SettingsError as exc:
        typer.secho(f"error: {exc}", err=True, fg="red")
        sys.exit(2)
    except Exception as exc:
        # Imported here: api.db pulls in SQLAlchemy, which `demcal --help` should not pay for.
        from api.db import SchemaOutOfDateError

        if not isinstance(exc, SchemaOutOfDateError):
            raise
        typer.secho(f"error: {exc}", err=True, fg="red")
        sys.exit(2)

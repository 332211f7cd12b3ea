"""``demcal config``: show the settings in effect, so an operator can see what the process sees."""

from __future__ import annotations

import json

import typer

from api.commands.console import cli_console
from api.settings import Settings, get_settings


def register(app: typer.Typer) -> None:
    @app.command("config")
    def config(as_json: bool = typer.Option(False, "--json", help="Print one JSON object.")) -> None:
        """Show every setting, its value and the DEMCAL_* variable that sets it."""
        settings = get_settings()
        values = settings.model_dump(mode="json")
        if as_json:
            typer.echo(json.dumps(values, indent=2))
            return
        from rich.table import Table

        table = Table("variable", "value", "meaning")
        for name, field in Settings.model_fields.items():
            table.add_row(f"DEMCAL_{name.upper()}", str(values[name]), field.description or "")
        cli_console().print(table)

"""``demcal db upgrade|current``: apply the store's migrations, or show where the schema is."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    db_app = typer.Typer(help="The database schema (Alembic migrations).", no_args_is_help=True)
    app.add_typer(db_app, name="db")

    @db_app.command("upgrade")
    def upgrade(revision: str = typer.Argument("head", help="Target revision; 'head' = newest.")) -> None:
        """Apply migrations to DEMCAL_DATABASE_URL (creates the schema on an empty database)."""
        from api.db import create_db_engine, current_revision, upgrade_database
        from api.settings import get_settings

        url = get_settings().database_url
        upgrade_database(url, revision)
        engine = create_db_engine(url)
        where = engine.url.render_as_string(hide_password=True)
        typer.echo(f"database {where} at {current_revision(engine)}")
        engine.dispose()

    @db_app.command("current")
    def current() -> None:
        """Show the schema revision of DEMCAL_DATABASE_URL and whether it is the newest."""
        from api.db import create_db_engine, current_revision, head_revision
        from api.settings import get_settings

        engine = create_db_engine(get_settings().database_url)
        revision, head = current_revision(engine), head_revision()
        engine.dispose()
        state = "up to date" if revision == head else f"out of date (newest: {head}); run `demcal db upgrade`"
        typer.echo(f"{revision or 'empty'}: {state}")
        if revision != head:
            raise typer.Exit(1)

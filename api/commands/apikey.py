"""``demcal apikey create|revoke|list``: the API keys of the REST API, managed by the operator.

The token is printed once, at creation; only its sha256 is stored.
"""

from __future__ import annotations

import typer


def _store():
    from api.db import check_schema_current, create_db_engine
    from api.settings import get_settings
    from api.store import SqlStore

    engine = create_db_engine(get_settings().database_url)
    check_schema_current(engine)
    return SqlStore(engine)


def register(app: typer.Typer) -> None:
    key_app = typer.Typer(help="API keys for the REST API.", no_args_is_help=True)
    app.add_typer(key_app, name="apikey")

    @key_app.command("create")
    def create(
        owner: str = typer.Option(..., "--owner", help="Who the key belongs to; studies are per owner."),
        name: str = typer.Option("", "--name", help="A note to recognise the key by."),
        admin: bool = typer.Option(False, "--admin", help="The key sees every owner's objects."),
    ) -> None:
        """Create a key and print its token (shown only this once)."""
        from api.auth import create_key
        from api.errors import DemcalError

        store = _store()
        try:
            with store.session() as session:
                row, token = create_key(session, owner, name=name, admin=admin)
                key_id = row.id
        except DemcalError as exc:
            typer.secho(f"error: {exc.detail}", err=True, fg="red")
            raise typer.Exit(2) from None
        role = " (admin)" if admin else ""
        typer.secho(f"key {key_id} for {owner}{role}; keep this token secret:", err=True)
        typer.echo(token)

    @key_app.command("revoke")
    def revoke(key_id: int = typer.Argument(..., help="The key's id, from `demcal apikey list`.")) -> None:
        """Revoke a key: requests with it get 401 from now on."""
        from api.auth import revoke_key
        from api.errors import DemcalError

        try:
            with _store().session() as session:
                revoke_key(session, key_id)
        except DemcalError as exc:
            typer.secho(f"error: {exc.detail}", err=True, fg="red")
            raise typer.Exit(2) from None
        typer.echo(f"key {key_id} revoked")

    @key_app.command("list")
    def list_keys(owner: str = typer.Option(None, "--owner", help="Only this owner's keys.")) -> None:
        """List keys (id, owner, prefix, admin, created, revoked); tokens are never shown."""
        from api.auth import list_keys as keys

        with _store().session() as session:
            rows = keys(session, owner)
        for row in rows:
            revoked = row.revoked_at.isoformat(timespec="seconds") if row.revoked_at else "-"
            typer.echo(
                f"{row.id}\t{row.owner}\t{row.prefix}...\t{'admin' if row.admin else 'user'}\t"
                f"{row.created_at.isoformat(timespec='seconds')}\trevoked: {revoked}\t{row.name}"
            )

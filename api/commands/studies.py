"""``demcal studies list|show|pause|resume|cancel|export|archive|restore``: manage studies in the
database of ``DEMCAL_DATABASE_URL`` without a server, as an admin key would through the API.

The same services answer as the REST API (``api/services/``), so the status rules, messages and
export format are the API's: pause from created/running, resume from paused, cancel from
created/running/paused. A process driving the study (``serve`` or ``calibrate``) sees the
change at its next step and withdraws the study's work.

``archive`` writes a study and all its trials as one JSON file and ``restore`` puts it into
another database (``api/store/archive.py``), where ``demcal calibrate --resume`` continues it.
"""

from __future__ import annotations

import json
from pathlib import Path

import typer

EXIT_USER_ERROR = 2
ACTIONS = ("pause", "resume", "cancel")


def _store():
    from api.db import check_schema_current, create_db_engine
    from api.settings import get_settings
    from api.store import SqlStore

    engine = create_db_engine(get_settings().database_url)
    check_schema_current(engine)
    return SqlStore(engine)


def _operator():
    from api.auth import Principal

    return Principal(key_id=0, owner="cli", admin=True)


def _fail(message: str) -> None:
    typer.secho(f"error: {message}", err=True, fg="red")
    raise typer.Exit(EXIT_USER_ERROR)


def register(app: typer.Typer) -> None:
    studies_app = typer.Typer(help="Studies in the database, without a server.", no_args_is_help=True)
    app.add_typer(studies_app, name="studies")

    @studies_app.command("list")
    def list_(
        status: str | None = typer.Option(None, "--status", help="Only studies in this status."),
        limit: int = typer.Option(50, "--limit", min=1, max=500),
    ) -> None:
        """One line per study, newest first: id, status, trials done / total, generation, name."""
        from api.services import studies
        from optimizer.protocols import StudyStatus

        try:
            wanted = StudyStatus(status) if status else None
        except ValueError:
            _fail(f"--status {status}: use one of {', '.join(s.value for s in StudyStatus)}")
        page = studies.list_studies(_store(), _operator(), wanted, limit, 0)
        for item in page.items:
            typer.echo(
                f"{item.id}  {item.status.value:<9}  {item.trials_done:>5}/{item.trials_total:<5}  "
                f"{item.name}"
            )
        typer.echo(f"{page.total} studies" + (f" (first {limit})" if page.total > limit else ""))

    @studies_app.command("show")
    def show(study_id: str) -> None:
        """The study as GET /api/v1/studies/{id} returns it (JSON)."""
        typer.echo(json.dumps(_read(study_id).model_dump(mode="json"), indent=2))

    for action in ACTIONS:
        _register_action(studies_app, action)

    @studies_app.command("export")
    def export(
        study_id: str,
        output: Path = typer.Option(None, "--output", "-o", help="CSV file (default: stdout)."),
    ) -> None:
        """Every trial as CSV, the columns of GET /api/v1/studies/{id}/export.csv."""
        from api.errors import NotFoundError
        from api.services import trials

        try:
            columns, rows = trials.export_rows(_store(), study_id, _operator())
        except NotFoundError as exc:
            _fail(exc.detail.split(";")[0])
        text = "".join(trials.export_csv(columns, rows))
        if output is None:
            typer.echo(text, nl=False)
        else:
            output.write_text(text)
            typer.echo(f"{len(rows)} trials written to {output}")

    @studies_app.command("archive")
    def archive(
        study_id: str,
        output: Path = typer.Option(None, "--output", "-o", help="JSON file (default: STUDY_ID.json)."),
    ) -> None:
        """The study and every trial as one JSON file, to restore into another database."""
        from api.errors import NotFoundError

        try:
            document = _store().archive_study(study_id)
        except NotFoundError as exc:
            _unknown_study(exc)
        path = output or Path(f"{study_id}.json")
        path.write_text(json.dumps(document, separators=(",", ":")))
        typer.echo(f"{study_id}: {len(document['trials'])} trials written to {path}")

    @studies_app.command("restore")
    def restore(archive_file: Path) -> None:
        """Put an archived study into this database; continue it with demcal calibrate --resume."""
        from api.errors import ConflictError, InvalidInputError

        try:
            document = json.loads(archive_file.read_text())
        except OSError as exc:
            _fail(f"{archive_file}: {exc.strerror or exc}")
        except ValueError as exc:
            _fail(f"{archive_file} is not JSON ({exc}); give a file from `demcal studies archive`")
        store = _store()
        try:
            study_id = store.restore_study(document)
        except (ConflictError, InvalidInputError) as exc:
            _fail(exc.detail)
        from optimizer.protocols import FINISHED_STUDIES

        study = store.load_study(study_id)
        done = sum(1 for t in document["trials"] if t.get("state") == "done")
        # A finished study has nothing to continue: point at what it found instead.
        then = (
            f"see it with: demcal studies show {study_id}"
            if study.status in FINISHED_STUDIES
            else f"continue it with: demcal calibrate --resume {study_id}"
        )
        trials = len(document["trials"])
        typer.echo(f"{study_id}: restored, {study.status.value}, {done} of {trials} trials done; {then}")


def _unknown_study(exc) -> None:
    """Exit 2 on a study id this database does not hold, saying how to see the ones it does."""
    _fail(exc.detail.split(";")[0] + "; list them with `demcal studies list`")


def _read(study_id: str):
    from api.errors import NotFoundError
    from api.services import studies

    try:
        return studies.get_study(_store(), study_id, _operator())
    except NotFoundError as exc:
        _unknown_study(exc)


def _register_action(studies_app: typer.Typer, action: str) -> None:
    @studies_app.command(action, help=f"{action.capitalize()} a study (the API's status rules).")
    def change(study_id: str) -> None:
        from api.errors import ConflictError, NotFoundError
        from api.services import studies

        try:
            study = studies.change_status(_store(), study_id, action, _operator())
        except NotFoundError as exc:
            _unknown_study(exc)
        except ConflictError as exc:
            _fail(exc.detail)
        typer.echo(f"{study.id}: {study.status.value}")

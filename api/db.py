"""Database plumbing: engines, sessions, the unit of work, and the schema's migration state.

What it is for: make an engine that behaves the same on SQLite and PostgreSQL, give one
transaction helper (``unit_of_work``: commit on exit, roll back on error, as optuna's
``_create_scoped_session``), and run or check Alembic migrations with a configuration built in
code, so that it works from an installed package without an ``alembic.ini``.

What it must not do: know about tables' meaning (``api/store/``) or create tables behind
Alembic's back; the schema comes from migrations only, in tests as in production.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import sqlalchemy as sa
from sqlalchemy.orm import Session, sessionmaker

log = logging.getLogger(__name__)
# Alembic announces every plugin and context at INFO on each check; our own lines say what matters.
for _chatty in ("alembic.runtime.plugins", "alembic.runtime.migration"):
    logging.getLogger(_chatty).setLevel(logging.WARNING)

MIGRATIONS_DIR = Path(__file__).resolve().parent.parent / "migrations"


class SchemaOutOfDateError(RuntimeError):
    """The database is not at the newest migration; the message says to run ``demcal db upgrade``."""


def normalise_url(url: str | sa.URL) -> sa.URL:
    """psycopg 3 is the PostgreSQL driver we ship; a bare ``postgresql://`` would ask for psycopg2."""
    url = sa.make_url(url)
    if url.drivername == "postgresql":
        url = url.set(drivername="postgresql+psycopg")
    return url


def _sqlite_pragmas(dbapi_connection, _record) -> None:
    cursor = dbapi_connection.cursor()
    # Foreign keys make ON DELETE CASCADE work; WAL lets the API read while a CLI study writes;
    # busy_timeout makes a writer wait for the other instead of failing at once.
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA busy_timeout=10000")
    cursor.close()


def create_db_engine(url: str | sa.URL, **kwargs) -> sa.Engine:
    """An engine for SQLite or PostgreSQL with the per-dialect settings the store relies on."""
    url = normalise_url(url)
    if url.get_backend_name() == "sqlite":
        connect_args = {"check_same_thread": False, "timeout": 10}
        engine = sa.create_engine(url, connect_args=connect_args, **kwargs)
        sa.event.listen(engine, "connect", _sqlite_pragmas)
        return engine
    kwargs.setdefault("pool_pre_ping", True)
    kwargs.setdefault("pool_size", 10)
    kwargs.setdefault("max_overflow", 20)
    return sa.create_engine(url, **kwargs)


def session_factory(engine: sa.Engine) -> sessionmaker[Session]:
    # expire_on_commit=False: rows read in a unit of work stay usable after it commits.
    return sessionmaker(bind=engine, expire_on_commit=False)


@contextmanager
def unit_of_work(factory: sessionmaker[Session]) -> Iterator[Session]:
    """One transaction: commit if the block ends normally, roll back (and re-raise) otherwise."""
    session = factory()
    try:
        yield session
        session.commit()
    except BaseException:
        session.rollback()
        raise
    finally:
        session.close()


def alembic_config(url: str | sa.URL):
    """Alembic's configuration, built in code from the packaged ``migrations/`` directory."""
    from alembic.config import Config

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    # Alembic's ini interpolation treats '%' specially; URLs with escaped passwords contain it.
    rendered = normalise_url(url).render_as_string(hide_password=False).replace("%", "%%")
    config.set_main_option("sqlalchemy.url", rendered)
    return config


def upgrade_database(url: str | sa.URL, revision: str = "head") -> None:
    """Apply migrations up to ``revision`` (the newest by default)."""
    from alembic import command

    log.info("upgrading database schema to %s", revision)
    command.upgrade(alembic_config(url), revision)
    log.info("database schema upgraded to %s", revision)


def downgrade_database(url: str | sa.URL, revision: str) -> None:
    """Revert migrations down to ``revision`` (``base`` empties the schema)."""
    from alembic import command

    command.downgrade(alembic_config(url), revision)


def head_revision() -> str:
    from alembic.script import ScriptDirectory

    heads = ScriptDirectory(str(MIGRATIONS_DIR)).get_heads()
    return heads[0]


def current_revision(engine: sa.Engine) -> str | None:
    """The revision the database is at, or None for a database never migrated."""
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()


def check_schema_current(engine: sa.Engine) -> None:
    """Raise SchemaOutOfDateError unless the database is at the newest migration."""
    current = current_revision(engine)
    head = head_revision()
    if current != head:
        where = engine.url.render_as_string(hide_password=True)
        state = "has no demcal schema" if current is None else f"is at revision {current}"
        raise SchemaOutOfDateError(
            f"the database {where} {state}, this demcal needs revision {head}; "
            "run `demcal db upgrade` (with the same DEMCAL_DATABASE_URL) and start again"
        )

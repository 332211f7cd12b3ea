"""Alembic environment for demcal: runs migrations online against the configured URL.

The configuration is built in code (``api.db.alembic_config``), so no ``alembic.ini`` is needed.
``render_as_batch`` lets ALTER TABLE-style migrations work on SQLite. A caller may pass an open
connection in ``config.attributes["connection"]`` to migrate inside its own transaction.
"""

from __future__ import annotations

from alembic import context

from api.db import create_db_engine
from api.models import Base

config = context.config
target_metadata = Base.metadata


def _run(connection) -> None:
    context.configure(
        connection=connection,
        target_metadata=target_metadata,
        render_as_batch=connection.dialect.name == "sqlite",
        compare_type=True,
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    connection = config.attributes.get("connection")
    if connection is not None:
        _run(connection)
        return
    engine = create_db_engine(config.get_main_option("sqlalchemy.url"))
    try:
        with engine.connect() as connection:
            _run(connection)
    finally:
        engine.dispose()


if context.is_offline_mode():
    raise SystemExit("demcal migrations run online only: use `demcal db upgrade`")
run_migrations_online()

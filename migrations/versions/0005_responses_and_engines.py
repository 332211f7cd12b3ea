"""named responses and engines: trials.responses / engine / engine_options, simulations.responses
/ engine

Revision ID: 0005
Revises: 0004
Create Date: 2026-11-22

A trial's or simulation's measured quantities are the scenario's named responses
(``dem.scenarios.base.Response``), kept as one JSON object. Existing N_t values are carried over
as ``{"n_remaining": N_t}`` (the feeder's response name). The ``n_remaining`` column stays for the
views that still read it. Every existing trial ran on the built-in engine: ``engine = 'numba'``.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None

TABLES = ("trials", "simulations")
BATCH = 1000


def upgrade() -> None:
    for table in TABLES:
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column("responses", sa.JSON(), nullable=True))
            batch_op.add_column(sa.Column("engine", sa.String(32), nullable=False, server_default="numba"))
            if table == "trials":
                batch_op.add_column(sa.Column("engine_options", sa.JSON(), nullable=True))
        _copy(table)


def downgrade() -> None:
    for table in TABLES:
        with op.batch_alter_table(table, schema=None) as batch_op:
            if table == "trials":
                batch_op.drop_column("engine_options")
            batch_op.drop_column("engine")
            batch_op.drop_column("responses")


def _copy(name: str) -> None:
    """N_t from the column into the responses' ``n_remaining`` key, row by row (both dialects)."""
    connection = op.get_bind()
    table = sa.table(
        name, sa.column("id", sa.String), sa.column("n_remaining", sa.Integer), sa.column("responses", sa.JSON)
    )
    rows = connection.execute(sa.select(table.c.id, table.c.n_remaining).where(table.c.n_remaining.is_not(None)))
    updates = [{"key": row.id, "value": {"n_remaining": row.n_remaining}} for row in rows]
    statement = table.update().where(table.c.id == sa.bindparam("key")).values(responses=sa.bindparam("value"))
    for start in range(0, len(updates), BATCH):
        connection.execute(statement, updates[start : start + BATCH])

"""trial full_load_factor: copied out of the result, like wall_time_s and cost

Revision ID: 0010
Revises: 0009
Create Date: 2026-11-24

f2 is the cost or wall time of the whole protocol: a run's T x its result's ``full_load_factor``
(a run that emptied the tray stopped early; optimizer/objectives.py ``protocol_cost``). The
dashboard drew the runs at their own T, up to 6.4 times below the f2 their front was ranked on,
because the factor was only in the JSON result, which the trial lists never read. Existing
finished trials get the factor their result holds (1 where it has none: the value such a result
reads as, ``SimulationResult.full_load_factor``'s default).
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None

BATCH = 1000


def upgrade() -> None:
    with op.batch_alter_table("trials", schema=None) as batch_op:
        batch_op.add_column(sa.Column("full_load_factor", sa.Double(), nullable=False, server_default="1"))
    _copy()


def downgrade() -> None:
    with op.batch_alter_table("trials", schema=None) as batch_op:
        batch_op.drop_column("full_load_factor")


def _copy() -> None:
    """Each finished trial's factor from its JSON result, row by row (both dialects)."""
    connection = op.get_bind()
    table = sa.table(
        "trials", sa.column("id", sa.String), sa.column("result", sa.JSON),
        sa.column("full_load_factor", sa.Double),
    )
    rows = connection.execute(sa.select(table.c.id, table.c.result).where(table.c.result.is_not(None)))
    updates = [
        {"key": row.id, "value": float(row.result["full_load_factor"])}
        for row in rows
        if isinstance(row.result, dict) and row.result.get("full_load_factor") not in (None, 1, 1.0)
    ]
    statement = table.update().where(table.c.id == sa.bindparam("key")).values(
        full_load_factor=sa.bindparam("value")
    )
    for start in range(0, len(updates), BATCH):
        connection.execute(statement, updates[start : start + BATCH])

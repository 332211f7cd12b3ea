"""settled validations: a finished study's recommendation no longer reads ``pending``

Revision ID: 0009
Revises: 0008
Create Date: 2026-11-24

A recommendation reads ``pending`` while its study searches: its check on fresh seeds is to come.
A study cancelled or failed before its validation kept that label in the database, the API and
the CLI (only the dashboard mapped it). The store now stores such a recommendation ``not
validated`` when the study ends (``optimizer.validation.settled``); this carries existing studies
over. Data only, so the downgrade leaves the rows as they are: ``not validated`` is also true of
them under the previous revision.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None

FINISHED = ("done", "cancelled", "failed")  # optimizer.protocols.FINISHED_STUDIES as of this revision


def upgrade() -> None:
    connection = op.get_bind()
    studies = sa.table(
        "studies", sa.column("id", sa.String), sa.column("status", sa.String),
        sa.column("recommendation", sa.JSON),
    )
    rows = connection.execute(
        sa.select(studies.c.id, studies.c.recommendation).where(studies.c.status.in_(FINISHED))
    )
    for row in rows.all():
        recommendation = row.recommendation
        if isinstance(recommendation, dict) and recommendation.get("validation_status") == "pending":
            connection.execute(
                studies.update()
                .where(studies.c.id == row.id)
                .values(recommendation={**recommendation, "validation_status": "not validated"})
            )


def downgrade() -> None:
    pass

"""study start and finish times: studies.started_at, studies.finished_at

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-21

Existing studies are backfilled from what the database already knows: a study that has trials
started when its first trial was created; a finished one (done, cancelled, failed) finished at its
last update, which is the status change that ended it.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies", schema=None) as batch_op:
        batch_op.add_column(sa.Column("started_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True))
    op.execute(
        "UPDATE studies SET started_at = "
        "(SELECT MIN(trials.created_at) FROM trials WHERE trials.study_id = studies.id)"
    )
    op.execute(
        "UPDATE studies SET finished_at = updated_at WHERE status IN ('done', 'cancelled', 'failed')"
    )


def downgrade() -> None:
    with op.batch_alter_table("studies", schema=None) as batch_op:
        batch_op.drop_column("finished_at")
        batch_op.drop_column("started_at")

"""study driver lease: studies.driver, studies.driver_until

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-22

Which process drives a study (``demcal serve`` or ``demcal calibrate``) and until when its lease
holds; both take the lease in the database, so the rule is the same whether Redis is used or not.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies", schema=None) as batch_op:
        batch_op.add_column(sa.Column("driver", sa.String(200), nullable=True))
        batch_op.add_column(sa.Column("driver_until", sa.DateTime(timezone=True), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("studies", schema=None) as batch_op:
        batch_op.drop_column("driver_until")
        batch_op.drop_column("driver")

"""study change numbers: studies.change_number, and studies.trial_changes counts every change

Revision ID: 0007
Revises: 0006
Create Date: 2026-11-23

Cached views were versioned by the study row's ``updated_at``, a wall-clock stamp, and told
clients so by a hash of their bytes: a conditional GET had to find or build the view to answer
304. The study's counter (``trial_changes``, 0006) now also numbers the row's own writes, and
``change_number`` is the number of the row's last one (as ``trials.change_number`` is a trial's):
a view's version, and its ETag, is a number the database hands out. Existing studies get 0.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Plain ALTER TABLE, no batch copy (see 0006: a batch copy of ``studies`` may drop its trials).
    op.add_column("studies", sa.Column("change_number", sa.BigInteger(), nullable=False, server_default="0"))


def downgrade() -> None:
    op.drop_column("studies", "change_number")

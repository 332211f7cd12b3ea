"""trial change numbers: studies.trial_changes, trials.change_number

Revision ID: 0006
Revises: 0005
Create Date: 2026-11-23

The driver reads only the trials written since its last read. Its cursor was the newest
``updated_at`` it had read, and a write committed later with an older stamp (another process's
clock behind, a slow commit) fell behind it and was missed until the next full read. Every write
to a study's trials now takes the study's next change number, in commit order
(``StoreBase._change_numbers``). Existing trials get 0: a first read takes them all anyway.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    # Plain ALTER TABLE, no batch copy: SQLite adds and drops these columns in place, and a batch
    # copy of ``studies`` on the way down would drop the table, and its trials with it (ON DELETE
    # CASCADE with foreign keys on).
    op.add_column("studies", sa.Column("trial_changes", sa.BigInteger(), nullable=False, server_default="0"))
    op.add_column("trials", sa.Column("change_number", sa.BigInteger(), nullable=False, server_default="0"))
    op.create_index("ix_trials_study_change", "trials", ["study_id", "change_number"])


def downgrade() -> None:
    op.drop_index("ix_trials_study_change", table_name="trials")
    op.drop_column("trials", "change_number")
    op.drop_column("studies", "trial_changes")

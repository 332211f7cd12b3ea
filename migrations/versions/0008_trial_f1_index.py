"""trial f1 index: (study, f1_value), from which the recommendation reads its matching trials

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-23

The recommendation reads only the trials whose f1 is within the experiment's tolerance (344 of the
benchmark study's 10,000); without an index on f1 each build scanned all the study's rows, 3.0 of
its 10 ms of CPU on SQLite (benchmarks/README.md, API session 8, part 2).
"""

from __future__ import annotations

from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_index("ix_trials_study_f1", "trials", ["study_id", "f1_value"], unique=False)


def downgrade() -> None:
    op.drop_index("ix_trials_study_f1", table_name="trials")

"""trial list order index: (study, generation, individual, replicate) replaces (study, generation)

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-21
"""

from __future__ import annotations

from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("trials", schema=None) as batch_op:
        batch_op.drop_index("ix_trials_study_generation")
        batch_op.create_index(
            "ix_trials_study_order", ["study_id", "generation", "individual", "replicate"], unique=False
        )


def downgrade() -> None:
    with op.batch_alter_table("trials", schema=None) as batch_op:
        batch_op.drop_index("ix_trials_study_order")
        batch_op.create_index("ix_trials_study_generation", ["study_id", "generation"], unique=False)

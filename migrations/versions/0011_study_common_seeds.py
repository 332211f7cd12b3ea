"""study common_seeds: a study stored before the setting keeps the seeds it ran on

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-25

``common_seeds`` (``optimizer/seeds.py``) says which simulations share a seed; its default is now
``"generation"`` (new common seeds each generation). A study stored before the setting ran with
one seed per replicate for the whole study, and a definition without the key would read as the new
default on resume: its unfinished and later trials would run on other draws than its finished
ones. Its definition gets ``"study"``, the rule it ran under. The downgrade removes the key, which
the previous revision's definitions refuse.
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0011"
down_revision = "0010"
branch_labels = None
depends_on = None

STUDY_WIDE = "study"  # optimizer.seeds.STUDY_WIDE_SEEDS as of this revision


def _studies() -> sa.TableClause:
    return sa.table("studies", sa.column("id", sa.String), sa.column("definition", sa.JSON))


def upgrade() -> None:
    connection = op.get_bind()
    studies = _studies()
    for row in connection.execute(sa.select(studies.c.id, studies.c.definition)).all():
        definition = row.definition
        if isinstance(definition, dict) and "common_seeds" not in definition:
            connection.execute(
                studies.update()
                .where(studies.c.id == row.id)
                .values(definition={**definition, "common_seeds": STUDY_WIDE})
            )


def downgrade() -> None:
    connection = op.get_bind()
    studies = _studies()
    for row in connection.execute(sa.select(studies.c.id, studies.c.definition)).all():
        definition = row.definition
        if isinstance(definition, dict) and "common_seeds" in definition:
            kept = {key: value for key, value in definition.items() if key != "common_seeds"}
            connection.execute(studies.update().where(studies.c.id == row.id).values(definition=kept))

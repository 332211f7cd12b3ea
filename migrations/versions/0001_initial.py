"""initial schema: studies, trials, shapes, api keys, simulations

Revision ID: 0001
Revises: 
Create Date: 2026-11-21
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op


revision = '0001'
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:

    op.create_table('api_keys',
    sa.Column('id', sa.Integer(), autoincrement=True, nullable=False),
    sa.Column('name', sa.String(length=200), nullable=False),
    sa.Column('owner', sa.String(length=100), nullable=False),
    sa.Column('prefix', sa.String(length=16), nullable=False),
    sa.Column('token_sha256', sa.String(length=64), nullable=False),
    sa.Column('admin', sa.Boolean(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('revoked_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('last_used_at', sa.DateTime(timezone=True), nullable=True),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_api_keys')),
    sa.UniqueConstraint('token_sha256', name=op.f('uq_api_keys_token_sha256'))
    )
    with op.batch_alter_table('api_keys', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_api_keys_owner'), ['owner'], unique=False)

    op.create_table('shapes',
    sa.Column('id', sa.String(length=64), nullable=False),
    sa.Column('owner', sa.String(length=100), nullable=True),
    sa.Column('name', sa.String(length=200), nullable=False),
    sa.Column('file_type', sa.String(length=8), nullable=False),
    sa.Column('mass', sa.Double(), nullable=False),
    sa.Column('n_bytes', sa.Integer(), nullable=False),
    sa.Column('sha256', sa.String(length=64), nullable=False),
    sa.Column('data', sa.LargeBinary(), nullable=False),
    sa.Column('report', sa.JSON(), nullable=False),
    sa.Column('clump', sa.JSON(), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_shapes'))
    )
    with op.batch_alter_table('shapes', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_shapes_owner'), ['owner'], unique=False)

    op.create_table('simulations',
    sa.Column('id', sa.String(length=64), nullable=False),
    sa.Column('owner', sa.String(length=100), nullable=True),
    sa.Column('scenario', sa.JSON(), nullable=False),
    sa.Column('params', sa.JSON(), nullable=False),
    sa.Column('seed', sa.BigInteger(), nullable=False),
    sa.Column('timeout_s', sa.Double(), nullable=True),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=True),
    sa.Column('n_remaining', sa.Integer(), nullable=True),
    sa.Column('wall_time_s', sa.Double(), nullable=True),
    sa.Column('result', sa.JSON(), nullable=True),
    sa.Column('worker', sa.String(length=200), nullable=True),
    sa.Column('attempts', sa.Integer(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('finished_at', sa.DateTime(timezone=True), nullable=True),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_simulations'))
    )
    with op.batch_alter_table('simulations', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_simulations_owner'), ['owner'], unique=False)
        batch_op.create_index(batch_op.f('ix_simulations_state'), ['state'], unique=False)

    op.create_table('studies',
    sa.Column('id', sa.String(length=64), nullable=False),
    sa.Column('name', sa.String(length=200), nullable=False),
    sa.Column('owner', sa.String(length=100), nullable=True),
    sa.Column('status', sa.String(length=16), nullable=False),
    sa.Column('definition', sa.JSON(), nullable=False),
    sa.Column('generation', sa.Integer(), nullable=False),
    sa.Column('ga_state', sa.LargeBinary(), nullable=True),
    sa.Column('recommendation', sa.JSON(), nullable=True),
    sa.Column('message', sa.Text(), nullable=False),
    sa.Column('extra', sa.JSON(), nullable=False),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_studies'))
    )
    with op.batch_alter_table('studies', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_studies_owner'), ['owner'], unique=False)
        batch_op.create_index(batch_op.f('ix_studies_status'), ['status'], unique=False)

    op.create_table('trials',
    sa.Column('id', sa.String(length=100), nullable=False),
    sa.Column('study_id', sa.String(length=64), nullable=False),
    sa.Column('individual', sa.Integer(), nullable=False),
    sa.Column('generation', sa.Integer(), nullable=False),
    sa.Column('replicate', sa.Integer(), nullable=False),
    sa.Column('seed', sa.BigInteger(), nullable=False),
    sa.Column('params', sa.JSON(), nullable=False),
    sa.Column('scenario', sa.JSON(), nullable=False),
    sa.Column('timeout_s', sa.Double(), nullable=True),
    sa.Column('state', sa.String(length=16), nullable=False),
    sa.Column('status', sa.String(length=16), nullable=True),
    sa.Column('n_remaining', sa.Integer(), nullable=True),
    sa.Column('wall_time_s', sa.Double(), nullable=True),
    sa.Column('cost', sa.Double(), nullable=True),
    sa.Column('dt', sa.Double(), nullable=True),
    sa.Column('result', sa.JSON(), nullable=True),
    sa.Column('message', sa.Text(), nullable=False),
    sa.Column('worker', sa.String(length=200), nullable=True),
    sa.Column('attempts', sa.Integer(), nullable=False),
    sa.Column('pareto', sa.Boolean(), nullable=False),
    sa.Column('f1_value', sa.Double(), nullable=True),
    sa.Column('f1_kind', sa.String(length=8), nullable=True),
    sa.Column('f2_value', sa.Double(), nullable=True),
    sa.Column('f2_kind', sa.String(length=8), nullable=True),
    sa.Column('created_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('updated_at', sa.DateTime(timezone=True), nullable=False),
    sa.Column('started_at', sa.DateTime(timezone=True), nullable=True),
    sa.Column('finished_at', sa.DateTime(timezone=True), nullable=True),
    sa.ForeignKeyConstraint(['study_id'], ['studies.id'], name=op.f('fk_trials_study_id_studies'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('id', name=op.f('pk_trials')),
    sa.UniqueConstraint('study_id', 'individual', 'replicate', name=op.f('uq_trials_study_id_individual_replicate'))
    )
    with op.batch_alter_table('trials', schema=None) as batch_op:
        batch_op.create_index(batch_op.f('ix_trials_state'), ['state'], unique=False)
        batch_op.create_index('ix_trials_study_generation', ['study_id', 'generation'], unique=False)
        batch_op.create_index('ix_trials_study_pareto', ['study_id', 'pareto'], unique=False)
        batch_op.create_index('ix_trials_study_updated', ['study_id', 'updated_at'], unique=False)




def downgrade() -> None:

    with op.batch_alter_table('trials', schema=None) as batch_op:
        batch_op.drop_index('ix_trials_study_updated')
        batch_op.drop_index('ix_trials_study_pareto')
        batch_op.drop_index('ix_trials_study_generation')
        batch_op.drop_index(batch_op.f('ix_trials_state'))

    op.drop_table('trials')
    with op.batch_alter_table('studies', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_studies_status'))
        batch_op.drop_index(batch_op.f('ix_studies_owner'))

    op.drop_table('studies')
    with op.batch_alter_table('simulations', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_simulations_state'))
        batch_op.drop_index(batch_op.f('ix_simulations_owner'))

    op.drop_table('simulations')
    with op.batch_alter_table('shapes', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_shapes_owner'))

    op.drop_table('shapes')
    with op.batch_alter_table('api_keys', schema=None) as batch_op:
        batch_op.drop_index(batch_op.f('ix_api_keys_owner'))

    op.drop_table('api_keys')


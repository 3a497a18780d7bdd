"""Live association (issue 18): each deployment's live state and lease, the vehicles it
published (their sequence is the feed's cursor), and the detections it settled.

Revision ID: 0008
Revises: 0007
Create Date: 2026-11-25 03:03:35.823723
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

import roadlink.db.models

revision: str = '0008'
down_revision: str | None = '0007'
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table('live_association',
    sa.Column('deployment_id', sa.Uuid(), nullable=False),
    sa.Column('associator', sa.String(length=100), nullable=False),
    sa.Column('params', sa.JSON(), nullable=False),
    sa.Column('lateness', sa.Float(), nullable=False),
    sa.Column('active', sa.Boolean(), nullable=False),
    sa.Column('data_clock', sa.Float(), nullable=True),
    sa.Column('road_end', sa.Float(), nullable=True),
    sa.Column('received', sa.Integer(), nullable=False),
    sa.Column('processed', sa.Integer(), nullable=False),
    sa.Column('flush_requested', sa.Integer(), nullable=False),
    sa.Column('flushed', sa.Integer(), nullable=False),
    sa.Column('floor', sa.Float(), nullable=True),
    sa.Column('step_clock', sa.Float(), nullable=True),
    sa.Column('open_tracks', sa.Integer(), nullable=False),
    sa.Column('open_detections', sa.Integer(), nullable=False),
    sa.Column('next_vehicle', sa.Integer(), nullable=False),
    sa.Column('vehicles_published', sa.Integer(), nullable=False),
    sa.Column('late_detections', sa.Integer(), nullable=False),
    sa.Column('lease_owner', sa.String(length=200), nullable=True),
    sa.Column('lease_expires_at', roadlink.db.models.UTCDateTime(timezone=True), nullable=True),
    sa.Column('created_at', roadlink.db.models.UTCDateTime(timezone=True), nullable=False),
    sa.Column('last_step_at', roadlink.db.models.UTCDateTime(timezone=True), nullable=True),
    sa.ForeignKeyConstraint(['deployment_id'], ['deployment.id'], name=op.f('fk_live_association_deployment_id_deployment'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('deployment_id', name=op.f('pk_live_association'))
    )
    op.create_table('live_vehicle',
    sa.Column('seq', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), autoincrement=True, nullable=False),
    sa.Column('deployment_id', sa.Uuid(), nullable=False),
    sa.Column('vehicle_id', sa.String(length=40), nullable=False),
    sa.Column('revision', sa.Integer(), nullable=False),
    sa.Column('final', sa.Boolean(), nullable=False),
    sa.Column('confidence', sa.Float(), nullable=True),
    sa.Column('first_timestamp', sa.Float(), nullable=False),
    sa.Column('last_timestamp', sa.Float(), nullable=False),
    sa.Column('n_detections', sa.Integer(), nullable=False),
    sa.Column('detections_json', sa.Text(), nullable=False),
    sa.Column('published_at', roadlink.db.models.UTCDateTime(timezone=True), nullable=False),
    sa.ForeignKeyConstraint(['deployment_id'], ['deployment.id'], name=op.f('fk_live_vehicle_deployment_id_deployment'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('seq', name=op.f('pk_live_vehicle')),
    sa.UniqueConstraint('deployment_id', 'vehicle_id', 'revision', name='uq_live_vehicle_revision')
    )
    with op.batch_alter_table('live_vehicle', schema=None) as batch_op:
        batch_op.create_index('ix_live_vehicle_deployment_id_seq', ['deployment_id', 'seq'], unique=False)

    op.create_table('live_settled_detection',
    sa.Column('deployment_id', sa.Uuid(), nullable=False),
    sa.Column('batch_id', sa.Uuid(), nullable=False),
    sa.Column('row', sa.Integer(), nullable=False),
    sa.Column('timestamp', sa.Float(), nullable=False),
    sa.Column('vehicle_seq', sa.BigInteger().with_variant(sa.Integer(), 'sqlite'), nullable=True),
    sa.Column('late', sa.Boolean(), nullable=False),
    sa.ForeignKeyConstraint(['batch_id'], ['batch.id'], name=op.f('fk_live_settled_detection_batch_id_batch'), ondelete='CASCADE'),
    sa.ForeignKeyConstraint(['deployment_id'], ['deployment.id'], name=op.f('fk_live_settled_detection_deployment_id_deployment'), ondelete='CASCADE'),
    sa.PrimaryKeyConstraint('deployment_id', 'batch_id', 'row', name=op.f('pk_live_settled_detection'))
    )
    with op.batch_alter_table('live_settled_detection', schema=None) as batch_op:
        batch_op.create_index('ix_live_settled_detection_deployment_id_timestamp', ['deployment_id', 'timestamp'], unique=False)



def downgrade() -> None:
    with op.batch_alter_table('live_settled_detection', schema=None) as batch_op:
        batch_op.drop_index('ix_live_settled_detection_deployment_id_timestamp')

    op.drop_table('live_settled_detection')
    with op.batch_alter_table('live_vehicle', schema=None) as batch_op:
        batch_op.drop_index('ix_live_vehicle_deployment_id_seq')

    op.drop_table('live_vehicle')
    op.drop_table('live_association')

"""Detector features on detections: lane, length and vehicle_class, NULL where not reported.

Nullable columns only, so existing rows need no values (they reported none), and on PostgreSQL
adding them rewrites nothing. Downgrading drops them, and the features with them.

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-25 00:15:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("detection", schema=None) as batch_op:
        batch_op.add_column(sa.Column("lane", sa.SmallInteger(), nullable=True))
        batch_op.add_column(sa.Column("length", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("vehicle_class", sa.String(length=32), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("detection", schema=None) as batch_op:
        batch_op.drop_column("vehicle_class")
        batch_op.drop_column("length")
        batch_op.drop_column("lane")

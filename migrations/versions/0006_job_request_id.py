"""The request that created a job: job.request_id (its X-Request-ID), NULL for older jobs.

A nullable column only, so existing rows need no value, and on PostgreSQL adding it rewrites
nothing. Downgrading drops it.

Revision ID: 0006
Revises: 0004
Create Date: 2026-11-25 03:20:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("job", schema=None) as batch_op:
        batch_op.add_column(sa.Column("request_id", sa.String(length=128), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("job", schema=None) as batch_op:
        batch_op.drop_column("request_id")

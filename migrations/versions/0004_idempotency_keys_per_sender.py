"""A batch's Idempotency-Key belongs to its sender, as a job's does: the batch records the
principal that sent it, and the key is unique per deployment and principal.

Keys recorded before this revision were scoped and hashed by the old rules, so they are
forgotten (the batches and jobs stay), on the way up and on the way down.

Revision ID: 0004
Revises: 0003
Create Date: 2026-11-25 00:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def _forget_keys() -> None:
    op.execute("UPDATE batch SET idempotency_key = NULL, request_sha256 = NULL")
    op.execute("DELETE FROM job_idempotency_key")


def upgrade() -> None:
    _forget_keys()
    with op.batch_alter_table("batch", schema=None) as batch_op:
        batch_op.add_column(sa.Column("idempotency_principal", sa.String(length=64), nullable=True))
        batch_op.drop_constraint("uq_batch_deployment_id_idempotency_key", type_="unique")
        batch_op.create_unique_constraint(
            "uq_batch_idempotency_scope",
            ["deployment_id", "idempotency_principal", "idempotency_key"],
        )


def downgrade() -> None:
    _forget_keys()
    with op.batch_alter_table("batch", schema=None) as batch_op:
        batch_op.drop_constraint("uq_batch_idempotency_scope", type_="unique")
        batch_op.create_unique_constraint(
            "uq_batch_deployment_id_idempotency_key", ["deployment_id", "idempotency_key"]
        )
        batch_op.drop_column("idempotency_principal")

"""PostgreSQL compresses detection blocks with lz4, not pglz (issue 17 and 19, ingest).

A block (`roadlink.db.detection_blocks`) is megabytes per batch, so PostgreSQL compresses it as it
stores it (TOAST). Its default method, pglz, took about three quarters of the time of storing a
100,000-detection batch (196 ms against 48 ms uncompressed for a 4.6 MB block, measured on the
development machine); lz4 took 48 ms and stored fewer bytes (2.2 MB against 2.4 MB). So the
column's compression is lz4 where the server was built with it (`default_toast_compression` then
offers it; PostgreSQL 14 and later), and the blocks already stored are rewritten so that they are
lz4 too. The values are the same bytes either way; SQLite, which does not compress, is untouched.

Downgrading sets the column back to the server's default and rewrites the blocks with it.

Revision ID: 0011
Revises: 0010
Create Date: 2026-11-26 21:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

from alembic import op

revision: str = "0011"
down_revision: str | None = "0010"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    if _offers_lz4():
        _recompress("lz4")


def downgrade() -> None:
    if _offers_lz4():
        _recompress("default")


def _offers_lz4() -> bool:
    """Whether this is PostgreSQL and was built with lz4 (column compression is 14 and later)."""
    bind = op.get_bind()
    if bind.dialect.name != "postgresql":
        return False
    offered = bind.exec_driver_sql(
        "SELECT enumvals FROM pg_settings WHERE name = 'default_toast_compression'"
    ).scalar()
    return bool(offered) and "lz4" in offered


def _recompress(method: str) -> None:
    """Set the blocks' compression and store the existing ones again with it: a value copied as
    it is keeps its compression, a new one (the concatenation) takes the column's."""
    op.execute(f"ALTER TABLE detection_block ALTER COLUMN data SET COMPRESSION {method}")
    op.execute("UPDATE detection_block SET data = data || ''::bytea")

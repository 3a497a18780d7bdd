"""What a driver raises when `roadlink backup` is not the way to copy its database."""

from __future__ import annotations


class BackupAdvice(Exception):
    """This database is not copied by roadlink: the message says how to copy it instead."""

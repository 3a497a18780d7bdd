"""Storage: SQLAlchemy 2 models, the engine and session factory, and repository functions.

Alembic migrations (migrations/) are the only way the schema changes.
"""

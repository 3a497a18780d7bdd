"""The REST API: a FastAPI app factory, one router per resource."""

from roadlink.api.app import create_app

__all__ = ["create_app"]

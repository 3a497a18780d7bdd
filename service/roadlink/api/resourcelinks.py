"""`Location` of what a 201 or 202 created: the resource's own address."""

from __future__ import annotations

from typing import Any

from fastapi import Response

CREATED_HEADERS: dict[str, Any] = {
    "Location": {
        "description": "The created resource's path (GET it for its state).",
        "schema": {"type": "string"},
    }
}


def set_location(response: Response, path: str) -> None:
    response.headers["Location"] = path

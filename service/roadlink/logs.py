"""The service's logs: plain text or one JSON object a line (ROADLINK_LOG_FORMAT), for the API,
the workers and uvicorn's access log alike.

Each line carries the ids of what it is about: the request (`request_id`, from X-Request-ID or
made up), and, where one applies, the deployment, batch and job. They live in context variables,
set by the API for a request and by a worker for the job it runs, so that no log call has to pass
them on; a call may still give one itself (`extra={"job_id": ...}`), which wins.
"""

from __future__ import annotations

import json
import logging
import re
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from roadlink.settings import Settings

# The ids a log line may carry, in the order a JSON line shows them.
CONTEXT_FIELDS = ("request_id", "deployment_id", "batch_id", "job_id")
_CONTEXT: dict[str, ContextVar[str | None]] = {
    name: ContextVar(name, default=None) for name in CONTEXT_FIELDS
}

# An X-Request-ID we take as it comes: short, and of characters that are safe in a log line, a
# header and a URL (a gateway's UUID, a trace id, `gw1-0001`). Anything else is replaced by one
# of ours rather than refused: the id serves the operator, and a request is not wrong for it.
REQUEST_ID_PATTERN = re.compile(r"[A-Za-z0-9._:-]{1,128}")
MAX_REQUEST_ID_CHARS = 128

TEXT_FORMAT = "%(asctime)s %(levelname)s %(message)s"


def new_request_id() -> str:
    """A request id of our own (32 hex digits)."""
    return uuid.uuid4().hex


def accepted_request_id(given: str | None) -> str:
    """The request's id: the client's X-Request-ID when it is fit to log, else a new one."""
    if given is not None and REQUEST_ID_PATTERN.fullmatch(given):
        return given
    return new_request_id()


def current(name: str) -> str | None:
    """The id `name` (one of CONTEXT_FIELDS) of the work in progress, if any."""
    return _CONTEXT[name].get()


def current_request_id() -> str | None:
    return current("request_id")


@contextmanager
def log_context(**ids: object) -> Iterator[None]:
    """Within the block, log lines carry these ids (None values are left as they are)."""
    tokens = [
        (_CONTEXT[name], _CONTEXT[name].set(str(value)))
        for name, value in ids.items()
        if value is not None
    ]
    try:
        yield
    finally:
        for variable, token in reversed(tokens):
            variable.reset(token)


class ContextFilter(logging.Filter):
    """Puts the current ids on every record (unless the call gave its own)."""

    def filter(self, record: logging.LogRecord) -> bool:
        for name in CONTEXT_FIELDS:
            if getattr(record, name, None) is None:
                setattr(record, name, _CONTEXT[name].get())
        return True


class JsonFormatter(logging.Formatter):
    """One JSON object a line: timestamp (UTC, ISO 8601), level, logger, message, the ids that
    apply, the process; for uvicorn's access log the request's method, path and status too; the
    traceback, if any, as `exception`."""

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "timestamp": datetime.fromtimestamp(record.created, UTC).isoformat(
                timespec="milliseconds"
            ),
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        for name in CONTEXT_FIELDS:
            value = getattr(record, name, None)
            if value is not None:
                line[name] = str(value)
        line["process"] = record.process
        if record.name == "uvicorn.access":
            line.update(_access_fields(record))
        if record.exc_info:
            line["exception"] = self.formatException(record.exc_info)
        elif record.exc_text:
            line["exception"] = record.exc_text
        return json.dumps(line, ensure_ascii=False, default=str)


def _access_fields(record: logging.LogRecord) -> dict[str, Any]:
    # uvicorn logs '%s - "%s %s HTTP/%s" %d' with (client, method, path, http version, status).
    args = record.args
    if isinstance(args, tuple) and len(args) == 5:
        client, method, path, _version, status = args
        return {"client": client, "method": method, "path": path, "status": status}
    return {}


def configure_logging(settings: Settings, *, text_format: str = TEXT_FORMAT) -> None:
    """Send this process's log records to stderr in ROADLINK_LOG_FORMAT at ROADLINK_LOG_LEVEL.

    Replaces the root logger's handlers (a worker process inherits its parent's), so that each
    record is written once."""
    handler = logging.StreamHandler()
    handler.addFilter(ContextFilter())
    if settings.log_format == "json":
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(logging.Formatter(text_format))
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(settings.log_level.upper())

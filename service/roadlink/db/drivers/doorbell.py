"""Wake-ups between the processes that share one SQLite file: SQLite's LISTEN/NOTIFY, used
by the SQLite driver (`roadlink.db.drivers.sqlite`).

SQLite is embedded, so every process using a database file runs on one host. Each listening
process binds a Unix datagram socket in a directory named after the database file (one
directory per channel, named as the channel); a ring sends a datagram to every socket there.
A ring is a hint, never data: the listener re-reads the database, and keeps polling as before,
so a lost ring (a full socket buffer, a directory it may not write) only costs the poll interval
it would have waited anyway. A socket left behind by a process that died is removed by
the next ring that finds nobody listening on it.

Listeners of which one is enough (idle workers: one job wants one of them) say so in their
socket's name and mark themselves idle while they wait (a file beside the socket); a ring goes
to one of them marked idle, or to every one of them when none is (and to every other listener
of the channel, as before). (Every idle worker woke for every job, and all but one
read the queue and often tried the claim for nothing, on the same cores as the one that ran it.)
A listener woken so passes on what it took and did not do (`ring` again).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import select
import socket
import tempfile
import uuid
from pathlib import Path

from sqlalchemy import make_url

log = logging.getLogger(__name__)

MAX_DATAGRAM_BYTES = 60_000


def sqlite_file(database_url: str) -> Path | None:
    """The database file of a SQLite URL (resolved, so that every process names it alike);
    None for in-memory databases and other backends."""
    url = make_url(database_url)
    if url.get_backend_name() != "sqlite" or url.database in (None, "", ":memory:"):
        return None
    if url.database.startswith("file:"):  # URI filenames: no stable path to key on
        return None
    return Path(url.database).resolve()


def channel_directory(database_url: str, channel: str) -> Path | None:
    """Where the listeners of `channel` for this database bind their sockets (None: no
    doorbell for this database). Kept short: a socket path has at most 107 bytes."""
    # Worked out once per URL (every commit that notifies rings): a relative path names another
    # file in another working directory, hence the directory in the key.
    return _channel_directory(database_url, channel, os.getcwd(), tempfile.gettempdir())


@functools.lru_cache(maxsize=64)
def _channel_directory(database_url: str, channel: str, cwd: str, tmp: str) -> Path | None:
    path = sqlite_file(database_url)
    if path is None:
        return None
    digest = hashlib.sha256(str(path).encode()).hexdigest()[:16]
    return Path(tmp) / f"roadlink-{digest}" / channel


def ring(database_url: str, channel: str, message: bytes = b"") -> None:
    """Wake every process listening on `channel` of this database (best effort, never raises)."""
    directory = channel_directory(database_url, channel)
    if directory is None:
        return
    try:
        if not _ours(directory):
            return
        names = os.listdir(directory)
    except OSError:  # nobody has listened yet
        return
    sockets = [name for name in names if name.endswith(".sock")]
    idle = {name.removesuffix(IDLE) for name in names if name.endswith(IDLE)}
    many = [name for name in sockets if name.endswith(ONE_OF_MANY + ".sock")]
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sender:
        sender.setblocking(False)
        for name in sockets:  # every listener that is not one of many
            if name not in many:
                _send(sender, directory / name, message)
        for name in many:  # one of many that is idle, if one takes it
            if name.removesuffix(".sock") in idle and _send(sender, directory / name, message):
                return
        for name in many:  # else every one of them
            _send(sender, directory / name, message)


ONE_OF_MANY = ".one"
"""Names the socket of a listener of which one is enough (`Listener(..., one_of_many=True)`)."""

IDLE = ".idle"
"""The suffix of the mark such a listener leaves beside its socket while it waits."""


def _send(sender: socket.socket, path: Path, message: bytes) -> bool:
    """Whether the listener at `path` was sent the message."""
    try:
        sender.sendto(message[:MAX_DATAGRAM_BYTES], str(path))
        return True
    except (ConnectionRefusedError, FileNotFoundError):
        # Its process is gone: nobody will read this socket again.
        for stale in (path, path.with_suffix(IDLE)):
            with contextlib.suppress(OSError):
                stale.unlink()
    except OSError:  # its buffer is full (it is awake anyway), or not ours to write
        pass
    return False


def _ours(directory: Path) -> bool:
    """Whether the channel directory is this user's and private: a directory another local user
    made first must neither hear our job ids nor take our sockets."""
    status = directory.stat()
    return status.st_uid == os.getuid() and status.st_mode & 0o077 == 0


class Listener:
    """One process's socket on a channel; `wait` returns what rang it, or [] on a timeout.

    `one_of_many`: one such listener is enough for a ring (it marks itself idle while it waits,
    and a ring goes to one of those marked); the others are rung whatever the marks say."""

    def __init__(self, database_url: str, channel: str, *, one_of_many: bool = False) -> None:
        directory = channel_directory(database_url, channel)
        if directory is None:
            raise ValueError(f"no doorbell for {database_url!r}: not a SQLite file")
        kind = ONE_OF_MANY if one_of_many else ""
        self.path = directory / f"{os.getpid()}-{uuid.uuid4().hex[:8]}{kind}.sock"
        self._idle = self.path.with_suffix(IDLE) if one_of_many else None
        self._socket = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            for attempt in range(2):
                directory.mkdir(parents=True, exist_ok=True, mode=0o700)
                if not _ours(directory):
                    raise PermissionError(f"{directory} belongs to another user")
                try:
                    self._socket.bind(str(self.path))
                    break
                except FileNotFoundError:  # the last listener removed the directory meanwhile
                    if attempt:
                        raise
        except OSError:
            self._socket.close()
            raise
        self._socket.setblocking(False)

    def fileno(self) -> int:
        """The socket's descriptor (for select)."""
        return self._socket.fileno()

    def wait(self, timeout: float) -> list[bytes]:
        """Block until rung or `timeout` seconds pass; every message that was waiting."""
        marked = self._idle if timeout > 0 and self._mark_idle(self._idle) else None
        try:
            readable, _, _ = select.select([self._socket], [], [], max(timeout, 0.0))
        finally:
            if marked is not None:
                with contextlib.suppress(OSError):
                    marked.unlink()
        return self.drain() if readable else []

    @staticmethod
    def _mark_idle(path: Path | None) -> bool:
        if path is None:
            return False
        try:
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT, 0o600))
            return True
        except OSError:  # unmarked, it is rung as every listener is: only less often alone
            return False

    def drain(self) -> list[bytes]:
        """The messages waiting now, without blocking."""
        messages = []
        while True:
            try:
                messages.append(self._socket.recv(MAX_DATAGRAM_BYTES))
            except (BlockingIOError, InterruptedError):
                return messages
            except OSError:  # closed meanwhile
                return messages

    def close(self) -> None:
        """Stop listening and remove the socket, and its directories once they are empty (so
        that temporary databases leave nothing behind)."""
        self._socket.close()
        for path in (self.path, self._idle):
            if path is not None:
                with contextlib.suppress(OSError):
                    path.unlink()
        with contextlib.suppress(OSError):  # another listener's socket is still there
            self.path.parent.rmdir()
            self.path.parent.parent.rmdir()


def listen(database_url: str, channel: str, *, one_of_many: bool = False) -> Listener | None:
    """A listener on `channel` (see `Listener` for `one_of_many`), or None when this database has
    no doorbell or the socket cannot be made (the caller then polls, as it always may)."""
    if channel_directory(database_url, channel) is None:
        return None
    try:
        return Listener(database_url, channel, one_of_many=one_of_many)
    except OSError as exc:
        log.warning("cannot listen for %s jobs (%s); polling only", channel, exc)
        return None

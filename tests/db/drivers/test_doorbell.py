"""SQLite's doorbell: rings reach listeners in other processes, and nothing is left behind."""

import multiprocessing
import time

import pytest

from roadlink.db.drivers import doorbell

QUEUED = "queued"
FINISHED = "finished"


@pytest.fixture
def database_url(tmp_path):
    return f"sqlite:///{tmp_path / 'roadlink.db'}"


def _ring_later(database_url: str, channel: str, message: bytes) -> None:
    time.sleep(0.2)
    doorbell.ring(database_url, channel, message)


def test_a_ring_from_another_process_wakes_a_listener_with_its_message(database_url):
    listener = doorbell.listen(database_url, FINISHED)
    assert listener is not None
    try:
        ringer = multiprocessing.get_context("spawn").Process(
            target=_ring_later, args=(database_url, FINISHED, b"job-1\njob-2")
        )
        ringer.start()
        messages = listener.wait(30.0)
        ringer.join(30)
        assert messages == [b"job-1\njob-2"]
    finally:
        listener.close()


def test_every_listener_of_a_channel_hears_a_ring_and_other_channels_do_not(database_url):
    queued = [doorbell.listen(database_url, QUEUED) for _ in range(2)]
    finished = doorbell.listen(database_url, FINISHED)
    try:
        doorbell.ring(database_url, QUEUED)
        assert [listener.wait(5.0) for listener in queued] == [[b""], [b""]]
        assert finished.wait(0.05) == []
    finally:
        for listener in [*queued, finished]:
            listener.close()


def test_a_listener_on_another_database_is_not_rung(tmp_path, database_url):
    other = doorbell.listen(f"sqlite:///{tmp_path / 'other.db'}", QUEUED)
    try:
        doorbell.ring(database_url, QUEUED)
        assert other.wait(0.05) == []
    finally:
        other.close()


def test_a_socket_left_by_a_dead_process_is_removed_by_the_next_ring(database_url):
    directory = doorbell.channel_directory(database_url, QUEUED)
    listener = doorbell.listen(database_url, QUEUED)
    stale = doorbell.Listener(database_url, QUEUED)
    stale._socket.close()  # as if its process died: the file stays, nobody reads it
    try:
        doorbell.ring(database_url, QUEUED)
        assert not stale.path.exists()
        assert listener.wait(5.0) == [b""]
    finally:
        listener.close()
    assert not directory.exists(), "the last listener removes the directory"


def test_databases_without_a_file_have_no_doorbell():
    assert doorbell.channel_directory("sqlite://", QUEUED) is None
    assert doorbell.channel_directory("sqlite:///:memory:", QUEUED) is None
    assert doorbell.listen("postgresql+psycopg://u@h/db", QUEUED) is None
    doorbell.ring("sqlite://", QUEUED)  # nothing to ring, and no error


def test_every_process_names_a_database_file_alike(tmp_path, monkeypatch):
    absolute = doorbell.channel_directory(f"sqlite:///{tmp_path / 'x.db'}", QUEUED)
    monkeypatch.chdir(tmp_path)
    assert doorbell.channel_directory("sqlite:///./x.db", QUEUED) == absolute


def test_a_channel_directory_others_may_write_is_not_used(database_url):
    directory = doorbell.channel_directory(database_url, QUEUED)
    listener = doorbell.listen(database_url, QUEUED)
    try:
        directory.chmod(0o777)  # as if another local user had made it first
        doorbell.ring(database_url, QUEUED)
        assert listener.wait(0.05) == [], "no job news is sent into a directory others share"
        assert doorbell.listen(database_url, QUEUED) is None
    finally:
        directory.chmod(0o700)
        listener.close()


def _waiting(listener, heard):
    """A thread in which `listener` waits, as an idle worker does, and keeps what it heard."""
    import threading

    thread = threading.Thread(target=lambda: heard.append(listener.wait(5.0)), daemon=True)
    thread.start()
    return thread


def _idle_marks(database_url):
    return sorted(doorbell.channel_directory(database_url, QUEUED).glob(f"*{doorbell.IDLE}"))


def test_a_ring_wakes_one_idle_listener_of_many_and_every_other_listener(database_url):
    """Idle workers: one is enough for a job, so one of those waiting is rung; a listener that
    is not one of many (a result request's) hears every ring."""
    many = [doorbell.listen(database_url, QUEUED, one_of_many=True) for _ in range(2)]
    plain = doorbell.listen(database_url, QUEUED)
    heard = [[], []]
    try:
        threads = [_waiting(listener, heard[k]) for k, listener in enumerate(many)]
        deadline = time.monotonic() + 5
        while len(_idle_marks(database_url)) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(_idle_marks(database_url)) == 2  # both wait, marked idle
        doorbell.ring(database_url, QUEUED, b"job-1")
        assert plain.wait(5.0) == [b"job-1"]
        time.sleep(0.2)
        assert sorted(map(len, heard)) == [0, 1] and [[b"job-1"]] in heard
        woken = 0 if heard[0] else 1
        assert len(_idle_marks(database_url)) == 1  # the woken one is no longer idle
        doorbell.ring(database_url, QUEUED, b"job-2")  # the other one
        for thread in threads:
            thread.join(5.0)
        assert heard[1 - woken] == [[b"job-2"]]
        assert _idle_marks(database_url) == []
    finally:
        for listener in [*many, plain]:
            listener.close()


def test_with_none_of_many_idle_every_one_is_rung(database_url):
    """A worker busy with a job is not marked idle: when none is, all of them are rung (each
    looks for work when its job ends anyway)."""
    many = [doorbell.listen(database_url, QUEUED, one_of_many=True) for _ in range(2)]
    try:
        doorbell.ring(database_url, QUEUED, b"job-1")
        assert [listener.wait(0.0) for listener in many] == [[b"job-1"], [b"job-1"]]
    finally:
        for listener in many:
            listener.close()


def test_an_idle_mark_left_by_a_dead_listener_is_cleared_and_the_ring_goes_on(database_url):
    alive = doorbell.listen(database_url, QUEUED, one_of_many=True)
    directory = doorbell.channel_directory(database_url, QUEUED)
    (directory / f"999999-dead{doorbell.ONE_OF_MANY}.sock").touch()  # no one listens there
    (directory / f"999999-dead{doorbell.ONE_OF_MANY}{doorbell.IDLE}").touch()
    try:
        doorbell.ring(database_url, QUEUED, b"job-1")
        assert alive.wait(5.0) == [b"job-1"]
        assert sorted(p.name for p in directory.iterdir()) == [alive.path.name]
    finally:
        alive.close()

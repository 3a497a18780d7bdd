"""The worker loop: claim a job, run the association core on its detections, store the result.

Each worker is its own process (so numpy and scikit-learn never stall the API) running one job
at a time; a heartbeat thread renews the job's lease and reports progress meanwhile.
"""

from __future__ import annotations

import logging
import os
import signal
import socket
import threading
import time
import traceback
import uuid

from sqlalchemy import Engine

from service.association import DetectionError, associate
from service.association.associators import AssociationError
from service.db.engine import make_engine, make_session_factory, transaction
from service.db.repository import load_detections
from service.queue.jobs import (
    ClaimedJob,
    claim_next_job,
    complete_job,
    fail_job,
    has_runnable_job,
    heartbeat_job,
    release_job,
    rescue_expired_jobs,
)
from service.queue.wakeup import Wakeup, make_wakeup
from service.settings import Settings

log = logging.getLogger(__name__)


class JobInterrupted(Exception):
    """Raised inside the associator's progress callback to stop a job that is no longer ours
    (cancelled, or its lease was lost) or that must be handed back (the worker is stopping)."""


class Worker:
    """Drains the queue, one job at a time."""

    def __init__(self, settings: Settings, *, engine: Engine | None = None) -> None:
        self.settings = settings
        self.engine = engine or make_engine(settings.database_url)
        self.sessions = make_session_factory(self.engine)
        self.id = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self.stopping = threading.Event()
        self._last_rescue = 0.0

    def run(self, wakeup: Wakeup | None = None) -> None:
        """Work until `stopping` is set."""
        wakeup = wakeup or make_wakeup(self.settings.database_url)
        log.info("worker %s started", self.id)
        try:
            while not self.stopping.is_set():
                if not self.run_once():
                    wakeup.wait(self.settings.poll_seconds)
        finally:
            wakeup.close()
            log.info("worker %s stopped", self.id)

    def run_once(self) -> bool:
        """Rescue expired leases when due, then claim and run one job; False if none was queued."""
        self._rescue_when_due()
        with self.sessions() as session:
            if not has_runnable_job(session):
                return False
        with transaction(self.sessions) as session:
            job = claim_next_job(
                session, worker_id=self.id, lease_seconds=self.settings.lease_seconds
            )
        if job is None:
            return False
        self.run_job(job)
        return True

    def _rescue_when_due(self) -> None:
        # Every worker rescues, so a crashed worker's jobs come back as long as one worker lives.
        now = time.monotonic()
        if now - self._last_rescue < self.settings.lease_seconds / 4:
            return
        self._last_rescue = now
        with transaction(self.sessions) as session:
            requeued, failed = rescue_expired_jobs(session)
        if requeued or failed:
            log.warning("rescued expired leases: %d requeued, %d failed", requeued, failed)

    def run_job(self, job: ClaimedJob) -> None:
        """Run a claimed job to its end: succeeded, failed, queued again, or given up."""
        started = time.monotonic()
        progress = [0.0]
        lost = threading.Event()  # cancelled, or rescued by another worker
        done = threading.Event()

        def report(share: float) -> None:
            progress[0] = min(max(float(share), 0.0), 1.0)
            if lost.is_set() or self.stopping.is_set():
                raise JobInterrupted

        heartbeat = threading.Thread(
            target=self._heartbeat, args=(job, progress, lost, done), daemon=True
        )
        heartbeat.start()
        try:
            with transaction(self.sessions) as session:
                detections = load_detections(
                    session, deployment_id=job.deployment_id, selection=job.selection
                )
            result = associate(detections, job.associator, job.params, progress=report)
        except JobInterrupted:
            self._interrupted(job, lost)
            return
        except (AssociationError, DetectionError) as exc:
            # The input or parameters are wrong: running again would fail the same way.
            self._failed(job, str(exc), retry=False)
            return
        except Exception as exc:
            log.exception("job %s crashed", job.id)
            self._failed(
                job, f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=5)}", retry=True
            )
            return
        finally:
            done.set()
            heartbeat.join()
        if lost.is_set():
            self._interrupted(job, lost)
            return
        with transaction(self.sessions) as session:
            stored = complete_job(
                session,
                job_id=job.id,
                worker_id=self.id,
                result=result,
                duration_seconds=time.monotonic() - started,
            )
        if stored:
            log.info("job %s succeeded in %.3f s", job.id, time.monotonic() - started)
        else:
            log.info("job %s finished but was no longer ours; result discarded", job.id)

    def _heartbeat(
        self, job: ClaimedJob, progress: list[float], lost: threading.Event, done: threading.Event
    ) -> None:
        while not done.wait(self.settings.heartbeat_seconds):
            try:
                with transaction(self.sessions) as session:
                    ours = heartbeat_job(
                        session,
                        job_id=job.id,
                        worker_id=self.id,
                        lease_seconds=self.settings.lease_seconds,
                        progress=progress[0],
                    )
            except Exception:  # a transient database error: the next beat tries again
                log.exception("heartbeat of job %s failed", job.id)
                continue
            if not ours:
                lost.set()
                return

    def _interrupted(self, job: ClaimedJob, lost: threading.Event) -> None:
        if lost.is_set():
            log.info("job %s was cancelled or rescued elsewhere; stopped", job.id)
            return
        with transaction(self.sessions) as session:
            release_job(session, job_id=job.id, worker_id=self.id)
        log.info("job %s handed back to the queue (worker stopping)", job.id)

    def _failed(self, job: ClaimedJob, error: str, *, retry: bool) -> None:
        with transaction(self.sessions) as session:
            state = fail_job(
                session,
                job=job,
                worker_id=self.id,
                error=error,
                retry=retry,
                backoff_seconds=self.settings.retry_backoff_seconds,
            )
        log.info("job %s: %s -> %s", job.id, error.splitlines()[0], state)


def run_worker_process(settings: Settings) -> None:
    """Entry point of a worker process: work until SIGTERM or SIGINT, then stop cleanly.

    A job in progress is interrupted at its next progress report and handed back to the queue.
    """
    logging.basicConfig(
        level=settings.log_level.upper(),
        format="%(asctime)s %(levelname)s [worker %(process)d] %(message)s",
    )
    worker = Worker(settings)

    def stop(_signum: int, _frame: object) -> None:
        worker.stopping.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    try:
        worker.run()
    finally:
        worker.engine.dispose()

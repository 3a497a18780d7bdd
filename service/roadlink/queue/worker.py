"""The worker loop: claim a job, run the association core on its detections, store the result.

Each worker is its own process (so numpy and scikit-learn never stall the API) running one job
at a time in a child process of its own (so a job past its time limit can be killed without
losing the worker); a heartbeat thread renews the job's lease and reports progress meanwhile.
"""

from __future__ import annotations

import contextvars
import logging
import os
import signal
import socket
import threading
import time
import uuid

from sqlalchemy import Engine

from roadlink.db.engine import engine_for, make_session_factory, transaction
from roadlink.db.live_records import has_live_step, release_live_leases
from roadlink.db.repository import load_detections
from roadlink.logs import configure_logging, log_context
from roadlink.queue.associator_process import (
    AssociatorProcess,
    Died,
    Failed,
    Stopped,
    Succeeded,
    TimedOut,
)
from roadlink.queue.housekeeping import Housekeeping
from roadlink.queue.live_step import run_live_step
from roadlink.queue.liveness import WorkerLiveness
from roadlink.queue.transitions import (
    ClaimedJob,
    claim_next_job,
    complete_job,
    fail_job,
    has_runnable_job,
    heartbeat_job,
    release_job,
    rescue_expired_jobs,
)
from roadlink.queue.wakeup import Wakeup, make_wakeup
from roadlink.settings import Settings

log = logging.getLogger(__name__)


class Worker:
    """Drains the queue, one job at a time."""

    def __init__(self, settings: Settings, *, engine: Engine | None = None) -> None:
        self.settings = settings
        self.engine = engine or engine_for(settings)
        self.sessions = make_session_factory(self.engine)
        self.id = f"{socket.gethostname()}:{os.getpid()}:{uuid.uuid4().hex[:8]}"
        self.stopping = threading.Event()
        self.associator_process = AssociatorProcess()
        self._last_rescue = 0.0
        # What the last wake-up heard, until this worker takes work (then it passes on the rest).
        self._news: list[str] = []
        self._wakeup: Wakeup | None = None
        # The row for /metrics thrice a lease (live means beaten within a lease).
        self.liveness = WorkerLiveness(
            self.id,
            settings.worker_heartbeat_dir,
            settings.heartbeat_seconds,
            self.sessions,
            row_interval=settings.lease_seconds / 3,
        )

    def run(self, wakeup: Wakeup | None = None) -> None:
        """Work until `stopping` is set."""
        wakeup = self._wakeup = wakeup or make_wakeup(self.settings.database_url)
        self.associator_process.start()  # so that the first job does not wait for it
        housekeeping = Housekeeping(self.settings, self.sessions, self.stopping)
        housekeeping.start()
        log.info("worker %s started", self.id)
        try:
            while not self.stopping.is_set():
                self.liveness.beat()
                if not self.run_once():
                    self._news = wakeup.wait(self.settings.poll_seconds)
        finally:
            wakeup.close()
            self._release_live_leases()
            housekeeping.join(self.settings.webhook_timeout_seconds + 5)
            self.liveness.remove()
            log.info("worker %s stopped", self.id)

    def close(self) -> None:
        """Stop the associator process (the engine, when given by the caller, is theirs)."""
        self.associator_process.close()

    def run_once(self) -> bool:
        """Rescue expired leases when due, take a live association's step when one is due, then
        claim and run one job; False if there was nothing to do."""
        self._rescue_when_due()
        # Whether a step or a job is due, in one read (a job's wake-up paid two); after a step,
        # the job's question is asked again, as a job may have come meanwhile.
        with self.sessions() as session:
            live_due = has_live_step(session, worker_id=self.id)
            job_due = None if live_due else has_runnable_job(session)
        if live_due:
            self._pass_on()
        stepped = live_due and self._live_step()
        return self._job_once(job_due) or stepped

    def run_live_once(self) -> bool:
        """Take one due step of a live association (issue 18); False if none was due."""
        with self.sessions() as session:
            if not has_live_step(session, worker_id=self.id):
                return False
        return self._live_step()

    def _live_step(self) -> bool:
        try:
            return run_live_step(
                self.sessions, worker_id=self.id, lease_seconds=self.settings.lease_seconds
            )
        except Exception:  # the database went away: the next round tries again
            log.exception("a live association step failed")
            return False

    def _release_live_leases(self) -> None:
        """Hand this worker's live associations to the others at once, not at lease expiry."""
        try:
            with transaction(self.sessions) as session:
                release_live_leases(session, worker_id=self.id)
        except Exception:  # stopping anyway: the leases expire
            log.exception("could not release the live leases")

    def run_job_once(self) -> bool:
        """Claim and run one job; False if none was queued."""
        return self._job_once(None)

    def _job_once(self, due: bool | None) -> bool:
        """Claim and run one job, unless `due` (a read just made; None: not asked yet) says
        none is runnable."""
        if due is None:
            with self.sessions() as session:
                due = has_runnable_job(session)
        if not due:
            return False
        with transaction(self.sessions) as session:
            job = claim_next_job(
                session, worker_id=self.id, lease_seconds=self.settings.lease_seconds
            )
        if job is None:
            return False
        self._pass_on(done=str(job.id))
        self.run_job(job)
        return True

    def _pass_on(self, done: str | None = None) -> None:
        """Taking work after a wake-up: hand what else the wake-up named (other jobs, or news
        without an id) to another idle worker, as a ring wakes one of them (SQLite)."""
        news, self._news = self._news, []
        left = [n for n in news if n != done]
        if left and self._wakeup is not None:
            try:
                self._wakeup.pass_on(left)
            except Exception:  # a hint: the others poll anyway
                log.exception("could not pass the news on")

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
        """Run a claimed job to its end: succeeded, failed, queued again, or given up; its log
        lines carry its id, its deployment's, its batch's (when it has one) and the id of the
        request that created it."""
        batch_ids = getattr(job.selection, "batch_ids", None)
        with log_context(
            job_id=job.id,
            deployment_id=job.deployment_id,
            batch_id=batch_ids[0] if batch_ids and len(batch_ids) == 1 else None,
            request_id=job.request_id,
        ):
            log.info("job %s claimed (attempt %d of %d)", job.id, job.attempts, job.max_attempts)
            self._run_job(job)

    def _run_job(self, job: ClaimedJob) -> None:
        started = time.monotonic()
        limit = self.settings.job_timeout_seconds
        progress = [0.0]
        lost = threading.Event()  # cancelled, or rescued by another worker
        done = threading.Event()

        def record_progress(share: float) -> None:
            progress[0] = share

        # In this context, so that its log lines carry the job's ids as well.
        heartbeat = threading.Thread(
            target=contextvars.copy_context().run,
            args=(self._heartbeat, job, progress, lost, done),
            daemon=True,
        )
        heartbeat.start()
        try:
            with transaction(self.sessions) as session:
                detections = load_detections(
                    session, deployment_id=job.deployment_id, selection=job.selection
                )
            outcome = self.associator_process.run(
                detections,
                job.associator,
                job.params,
                time_limit=limit,
                should_stop=lambda: lost.is_set() or self.stopping.is_set(),
                on_progress=record_progress,
            )
        except Exception as exc:  # loading the detections failed (the database went away)
            error_id = _error_id()
            log.exception("job %s could not be run (error %s)", job.id, error_id)
            self._failed(
                job,
                f"the job's detections could not be loaded ({type(exc).__name__}); it will be "
                f"retried (error id {error_id})",
                retry=True,
            )
            return
        finally:
            done.set()
            heartbeat.join()
        if lost.is_set() or isinstance(outcome, Stopped):
            self._interrupted(job, lost)
        elif isinstance(outcome, TimedOut):
            self._failed(
                job,
                f"the job exceeded the time limit of {limit:g} s "
                "(ROADLINK_JOB_TIMEOUT_SECONDS) and was stopped",
                retry=False,
            )
        elif isinstance(outcome, Died):
            self._failed(
                job,
                f"the associator process died (exit code {outcome.exitcode}), "
                "e.g. killed for using too much memory",
                retry=True,
            )
        elif isinstance(outcome, Failed):
            error = outcome.error
            if outcome.details:  # not a message of the core's about the input: a failure
                error_id = _error_id()
                log.error("job %s failed (error %s):\n%s", job.id, error_id, outcome.details)
                error = f"the associator failed: {error} (error id {error_id})"
            self._failed(job, error, retry=False)
        else:
            self._succeeded(job, outcome, started)

    def _succeeded(self, job: ClaimedJob, outcome: Succeeded, started: float) -> None:
        with transaction(self.sessions) as session:
            stored = complete_job(
                session,
                job_id=job.id,
                worker_id=self.id,
                result=outcome.result,
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
                    if ours:  # alive, in the same transaction (no round trip of its own)
                        self.liveness.beat(session)
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


def _error_id() -> str:
    """The id under which the log holds what a job's short error leaves out."""
    return uuid.uuid4().hex[:12]


# How often a worker process checks that the process that started it is still there.
PARENT_CHECK_SECONDS = 1.0


def _stop_when_orphaned(stopping: threading.Event, parent_pid: int) -> None:
    """Stop, as on SIGTERM, once the parent is gone (killed with SIGKILL, say): a worker must not
    run jobs beside a restarted server, re-parented to PID 1. The parent passes its pid, since it
    may already be gone when this process gets to ask for it."""

    def watch() -> None:
        while True:
            if os.getppid() != parent_pid:
                log.warning("the process that started this worker is gone; stopping")
                stopping.set()
            if stopping.wait(PARENT_CHECK_SECONDS):
                return

    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def run_worker_process(settings: Settings, parent_pid: int | None = None) -> None:
    """Entry point of a worker process: work until SIGTERM or SIGINT, then stop cleanly.

    A job in progress is interrupted at its next progress report and handed back to the queue.
    """
    configure_logging(
        settings, text_format="%(asctime)s %(levelname)s [worker %(process)d] %(message)s"
    )
    worker = Worker(settings)

    def stop(_signum: int, _frame: object) -> None:
        worker.stopping.set()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    if parent_pid is not None:  # started by a pool (not `roadlink worker` as one process)
        _stop_when_orphaned(worker.stopping, parent_pid)
        # Beside the API on the same cores, as low as the deployment puts association below
        # its requests (ROADLINK_WORKER_NICENESS; 0 by default, docs/deploy.md).
        os.nice(settings.worker_niceness)
    try:
        worker.run()
    finally:
        worker.close()
        worker.engine.dispose()

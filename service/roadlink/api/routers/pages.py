"""Pages for a browser: a job's page at /jobs/{job_id}, plain server-rendered HTML.

No build step and no JavaScript: while the job is queued or running the page shows its state and
progress and refreshes itself (`<meta http-equiv="refresh">`); once it succeeded, the plot
(inline SVG), the metrics and a table of the targets with their detections; if it failed, the
error. Everything from the database is escaped by Jinja2's autoescaping; the plot is the SVG
`roadlink.plots` renders (matplotlib escapes its text).

Who may see a page (a browser sends no Authorization header, and an API key must not go into a
URL): a request carrying `?token=` from `POST /v1/jobs/{id}/page-link` (see
`service/roadlink/api/pagelinks.py`), or an `Authorization: Bearer` key, allowed by the same rule as
`GET /v1/jobs/{job_id}`; anyone when ROADLINK_AUTH=disabled. The page is outside /v1 and the
OpenAPI document: it is for people, not clients.
"""

from __future__ import annotations

import json
import uuid
from collections import Counter
from dataclasses import dataclass, field
from typing import Annotated, Any
from urllib.parse import urlencode

import numpy as np
from fastapi import APIRouter, Query, Request
from fastapi.responses import HTMLResponse
from markupsafe import Markup
from sqlalchemy.orm import Session

from roadlink.api.deps import SessionDep, SettingsDep
from roadlink.api.errors import ApiProblem
from roadlink.api.htmlpages import (
    REFRESH_SECONDS,
    SECURITY_HEADERS,
    PageDenied,
    check_page_access,
    message_page,
    templates,
)
from roadlink.api.jobresults import CachedResult, JobResultCache, job_result
from roadlink.api.pagelinks import token_key
from roadlink.association.scores import wrongly_grouped
from roadlink.db import repository
from roadlink.db.json_columns import BatchSelection, Selection
from roadlink.db.models import JobState
from roadlink.plots import PLOT_KINDS, target_colours

router = APIRouter(tags=["pages"], include_in_schema=False)

MAX_LISTED_DETECTIONS = 20_000
"""Beyond this many, the targets are listed without their detections (the page would be too
large to be useful); the result route has them all."""


@router.get("/jobs/{job_id}", name="job_page", response_class=HTMLResponse)
def job_page(
    job_id: str,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    kind: Annotated[str, Query()] = "time-space",
    token: Annotated[str | None, Query()] = None,
) -> HTMLResponse:
    """A job's page (see the module docstring)."""
    try:
        parsed = uuid.UUID(job_id)
    except ValueError:
        return message_page(404, "No such job", f"'{job_id}' is not a job id.")
    try:
        if settings.auth != "disabled":
            _check_access(request, session, parsed, token)
    except PageDenied as denied:
        return message_page(denied.status, "Not allowed", denied.message, denied.headers)
    if kind not in PLOT_KINDS:
        return message_page(
            422, "Unknown plot", f"There is no plot kind '{kind}'; try {', '.join(PLOT_KINDS)}."
        )
    job = repository.get_job(session, job_id=parsed)
    if job is None:
        return message_page(404, "No such job", f"There is no job {parsed}.")
    context: dict[str, Any] = {
        "job": job,
        "params_json": json.dumps(job.params, sort_keys=True),
        "selection": _describe_selection(job.selection),
        "refresh": None if job.state.finished else REFRESH_SECONDS,
        "kind": kind,
        # The links keep the token, so that switching plots works from a page link.
        "kind_links": [
            (k, "?" + urlencode({"kind": k} | ({"token": token} if token else {})))
            for k in PLOT_KINDS
        ],
    }
    if job.state == JobState.SUCCEEDED:
        cache: JobResultCache = request.app.state.job_results
        try:
            cached = job_result(session, cache, parsed, settings.max_view_detections)
        except ApiProblem as refused:
            if refused.status != 413:
                raise
            context["view_refused"] = refused.detail
        else:
            context["view"] = _result_view(cached, kind)
    html = templates.get_template("job.html").render(context)
    return HTMLResponse(html, headers=SECURITY_HEADERS)


def _check_access(request: Request, session: Session, job_id: uuid.UUID, token: str | None) -> None:
    # The page shows what GET /v1/jobs/{job_id} and its result routes show.
    check_page_access(
        request,
        session,
        token=token,
        token_key=lambda text: token_key(session, token=text, job_id=job_id),
        link_route=f"/v1/jobs/{job_id}/page-link",
        as_route=("GET", "/v1/jobs/{job_id}"),
        path_params={"job_id": str(job_id)},
    )


@dataclass
class DetectionRow:
    detection_id: str
    sensor_id: str
    position: float
    timestamp: float
    velocity: float
    label: str | None
    wrong: bool
    link_confidence: float | None = None
    # The detector features, where reported (the page shows a column for each the job has).
    lane: int | None = None
    length: float | None = None
    vehicle_class: str | None = None


@dataclass
class TargetRow:
    name: str
    colour: str
    n_detections: int
    start: float
    end: float
    first_position: float
    last_position: float
    mean_speed: float | None
    monotone: bool
    label: str | None
    label_share: str | None
    n_wrong: int
    confidence: float | None = None
    length: float | None = None
    vehicle_class: str | None = None
    detections: list[DetectionRow] = field(default_factory=list)


@dataclass
class ResultView:
    svg: Markup
    metrics: list[tuple[str, str, str]] | None
    targets: list[TargetRow]
    unassigned: list[DetectionRow]
    labelled: bool
    n_detections: int
    n_wrong: int
    listed: bool
    has_confidence: bool
    features: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()


METRIC_NAMES = (
    ("accuracy", "Accuracy", "detections whose group is matched to their own target"),
    ("pairwise_precision", "Pairwise precision", "pairs put together that belong together"),
    ("pairwise_recall", "Pairwise recall", "pairs belonging together that were put together"),
    ("pairwise_f1", "Pairwise F1", "harmonic mean of the two"),
    ("ari", "Adjusted Rand index", "1 is perfect, 0 is chance"),
    ("complete_targets", "Complete targets", "targets grouped exactly right"),
)


def _result_view(cached: CachedResult, kind: str) -> ResultView:
    result = cached.result
    d = result.detections
    labelled = bool(d.labelled.any())
    wrong = wrongly_grouped(result.groups, d.target)
    listed = len(d) <= MAX_LISTED_DETECTIONS

    links = result.link_confidence
    features = d.features
    reported = {name: d.feature_values(name) for name in features}

    def row(i: int) -> DetectionRow:
        link = None if links is None or np.isnan(links[i]) else float(links[i])
        return DetectionRow(
            **{name: values[i] for name, values in reported.items()},
            detection_id=str(d.detection_id[i]),
            sensor_id=str(d.sensor_id[i]),
            position=float(d.position[i]),
            timestamp=float(d.timestamp[i]),
            velocity=float(d.velocity[i]),
            label=None if d.target[i] is None else str(d.target[i]),
            wrong=bool(wrong[i]),
            link_confidence=link,
        )

    colours = target_colours(result.n_targets)
    targets = []
    for k, (members, trajectory) in enumerate(
        zip(result.target_members(), cached.trajectories, strict=True)
    ):
        labels = Counter(str(t) for t in d.target[members] if t is not None)
        top = labels.most_common(1)
        span = trajectory.end - trajectory.start
        first, last = trajectory.passes[0], trajectory.passes[-1]
        targets.append(
            TargetRow(
                name=f"T{k + 1}",
                colour=_hex(colours[k]),
                n_detections=int(members.size),
                start=trajectory.start,
                end=trajectory.end,
                first_position=first.position,
                last_position=last.position,
                mean_speed=(last.position - first.position) / span if span > 0 else None,
                monotone=trajectory.monotone,
                label=top[0][0] if top else None,
                label_share=f"{top[0][1]}/{members.size}" if top else None,
                n_wrong=int(wrong[members].sum()),
                confidence=result.target_confidence(members),
                **result.target_features(members, features),
                detections=[row(int(i)) for i in members] if listed else [],
            )
        )
    unassigned = np.flatnonzero(result.groups < 0)
    metrics = None
    if result.metrics is not None:
        values = result.metrics.to_dict()
        metrics = [
            (title, f"{values[name]:.3f}" if name == "ari" else f"{values[name]:.1%}", meaning)
            for name, title, meaning in METRIC_NAMES
        ]
    svg = cached.plot(kind, "svg").decode()
    return ResultView(
        # From the <svg> element on: the XML declaration and DOCTYPE do not belong inside HTML.
        svg=Markup(svg[svg.index("<svg") :]),
        metrics=metrics,
        targets=targets,
        unassigned=[row(int(i)) for i in unassigned] if listed else [],
        labelled=labelled,
        n_detections=len(d),
        n_wrong=int(wrong.sum()),
        listed=listed,
        has_confidence=links is not None,
        features=features,
        warnings=result.warnings,
    )


def _hex(colour: tuple[float, float, float, float]) -> str:
    return "#" + "".join(f"{round(255 * c):02x}" for c in colour[:3])


def _describe_selection(selection: Selection) -> str:
    if isinstance(selection, BatchSelection):
        ids = [str(b) for b in selection.batch_ids]
        return ("batch " if len(ids) == 1 else "batches ") + ", ".join(ids)
    left = "-inf" if selection.start is None else f"{selection.start:g}"
    right = "+inf" if selection.end is None else f"{selection.end:g}"
    return f"the deployment's detections with timestamps in [{left}, {right})"

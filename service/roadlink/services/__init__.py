"""What a request or a worker does, below the HTTP API and above storage and the queue: store a
batch, resolve and enqueue a job, replay an idempotent request, wait for a job to finish.

Nothing here knows HTTP: a problem with a request is raised as `ServiceProblem`
(`services/problems.py`), which the API answers as problem details in one place
(`api/errors.py`)."""

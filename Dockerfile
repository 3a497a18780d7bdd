# syntax=docker/dockerfile:1
# roadlink: the REST service and its queue workers, in one image.
#   docker build -t roadlink .
#   docker run --rm -p 8000:8000 roadlink      # API + workers on the embedded SQLite default
#   docker run --rm roadlink worker            # workers only (scale-out on PostgreSQL)
# Configuration is through ROADLINK_* environment variables only (see docs/deploy.md).

# A patch-level tag, so that a rebuild gets the same interpreter; bump it on purpose.
ARG PYTHON_IMAGE=python:3.11.13-slim-bookworm
# Must equal pyproject.toml's version (tests/deploy checks it): pip then installs exactly the wheel
# built below, and the label tells which release an image holds.
ARG ROADLINK_VERSION=0.1.0

# ---- base: what both stages share ----------------------------------------------------------------
FROM ${PYTHON_IMAGE} AS base
ARG ROADLINK_VERSION
LABEL org.opencontainers.image.title="roadlink" \
      org.opencontainers.image.description="Group anonymous roadside sensor detections into one row per vehicle: REST service and job-queue workers." \
      org.opencontainers.image.licenses="MIT" \
      org.opencontainers.image.version="${ROADLINK_VERSION}"
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore

# ---- build: the roadlink wheel and the wheels of everything it needs ------------------------------
FROM base AS build
WORKDIR /src
# Only what the wheel is made of, so editing tests or docs does not invalidate this layer.
COPY pyproject.toml README.md ./
COPY service/ service/
COPY migrations/ migrations/
# Dependencies are resolved here, once, into /wheels; the runtime stage then installs offline from
# them and never sees a compiler, a build backend or the source tree.
RUN pip wheel --no-cache-dir --wheel-dir /wheels ".[postgres]"

# ---- runtime: the installed wheel, nothing else ---------------------------------------------------
FROM base AS runtime
ARG ROADLINK_VERSION
ARG ROADLINK_UID=10001
ENV ROADLINK_PORT=8000

# The wheels are bind-mounted from the build stage rather than copied, so they never land in a
# layer of the final image; --no-index proves the build stage resolved everything.
RUN --mount=type=bind,from=build,source=/wheels,target=/wheels \
    pip install --no-cache-dir --no-index --find-links=/wheels "roadlink[postgres]==${ROADLINK_VERSION}" \
    && useradd --system --uid "${ROADLINK_UID}" --user-group \
       --home-dir /var/lib/roadlink --create-home --shell /usr/sbin/nologin roadlink

# The working directory is the non-root user's home, so the embedded SQLite default (./roadlink.db)
# is writable there; mount a volume on it to keep that database.
WORKDIR /var/lib/roadlink
USER ${ROADLINK_UID}

EXPOSE 8000

# Slim images have no curl: the interpreter's urllib does the probe. urlopen raises on a refused
# connection, a timeout or any non-2xx answer, and an uncaught exception exits 1 = unhealthy.
HEALTHCHECK --interval=15s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:' + os.environ.get('ROADLINK_PORT', '8000') + '/healthz', timeout=4)"]

ENTRYPOINT ["roadlink"]
CMD ["serve", "--host", "0.0.0.0"]

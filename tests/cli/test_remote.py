"""The remote commands (submit, result, jobs) against a real `roadlink serve` with a worker."""

from __future__ import annotations

import json

import httpx
import pytest
from typer.testing import CliRunner

from roadlink.association import associate
from roadlink.association.csvio import read_detections_csv
from roadlink.cli import app
from tests.cli.conftest import Served
from tests.live_server import free_port

pytestmark = pytest.mark.slow

runner = CliRunner()


def submitted(served: Served, *extra: str) -> tuple[str, str, str]:
    """Run `roadlink submit --wait`; the batch id, the job id and what it printed."""
    argv = ["submit", str(served.csv), "--deployment", served.deployment, "--wait", *extra]
    done = runner.invoke(app, argv, env=served.env)
    assert done.exit_code == 0, done.output
    ids = dict(line.split(" ", 1) for line in done.stdout.splitlines()[:2])
    return ids["batch"], ids["job"], done.stdout


def test_submit_waits_for_the_job_and_prints_the_summary_the_core_gives(served):
    _, job, printed = submitted(served, "--associator", "kmeans++")
    expected = associate(read_detections_csv(served.csv.read_text()), "kmeans++")
    assert f"kmeans++: 100 detections -> {expected.to_dict()['n_targets']} targets" in printed
    assert f"accuracy={expected.metrics.accuracy:.4f}" in printed  # type: ignore[union-attr]
    listed = runner.invoke(app, ["jobs", "--state", "succeeded"], env=served.env)
    assert listed.exit_code == 0, listed.output
    assert job in listed.stdout
    queued = runner.invoke(app, ["jobs", "--state", "queued"], env=served.env)
    assert job not in queued.stdout


def test_jobs_follows_the_pages_the_server_sends(served):
    """With pages of one job, `jobs` follows `next` to list each of them once, newest first,
    and stops at --limit."""
    submitted(served)
    submitted(served)
    headers = {"Authorization": f"Bearer {served.key}"}
    whole = httpx.get(f"{served.url}/v1/jobs", params={"limit": 1000}, headers=headers).json()
    expected = [job["id"] for job in whole["items"]]
    assert len(expected) >= 2 and whole["next"] is None
    paged = runner.invoke(app, ["jobs", "--page-size", "1", "--limit", "1000"], env=served.env)
    assert paged.exit_code == 0, paged.output
    assert [line.split("\t")[0] for line in paged.stdout.splitlines()[1:]] == expected
    two = runner.invoke(app, ["jobs", "--page-size", "1", "--limit", "2"], env=served.env)
    assert [line.split("\t")[0] for line in two.stdout.splitlines()[1:]] == expected[:2]


def test_submit_passes_the_associators_parameters(served):
    _, job, _ = submitted(served, "--associator", "kmeans", "--param", "n_targets=3")
    shown = runner.invoke(app, ["result", job, "--json"], env=served.env)
    assert json.loads(shown.stdout)["n_targets"] == 3


def test_result_writes_json_and_csv_files_as_the_server_has_them(served, tmp_path):
    _, job, _ = submitted(served)
    headers = {"Authorization": f"Bearer {served.key}"}
    for option, fmt in (("--json", "json"), ("--csv", "csv")):
        written = tmp_path / f"result.{fmt}"
        done = runner.invoke(app, ["result", job, option, "-o", str(written)], env=served.env)
        assert done.exit_code == 0, done.output
        stored = httpx.get(
            f"{served.url}/v1/jobs/{job}/result", params={"format": fmt}, headers=headers
        )
        if fmt == "json":
            assert json.loads(written.read_text()) == stored.json()
        else:
            assert written.read_text() == stored.text


def test_a_bad_key_is_one_clear_line_and_exit_code_1(served):
    done = runner.invoke(app, ["jobs", "--key", "rl_00000000_nope"], env=served.env)
    assert done.exit_code == 1
    assert done.stderr.startswith("error: 401 Unauthorized: ")
    assert len(done.stderr.strip().splitlines()) == 1


def test_an_unknown_deployment_or_a_bad_parameter_says_so(served):
    nowhere = "00000000-0000-0000-0000-000000000000"
    done = runner.invoke(app, ["submit", str(served.csv), "--deployment", nowhere], env=served.env)
    assert done.exit_code == 1
    assert done.stderr.strip() == f"error: 404 Not Found: there is no deployment {nowhere}"
    bad = runner.invoke(
        app,
        ["submit", str(served.csv), "--deployment", served.deployment, "--param", "nope"],
        env=served.env,
    )
    assert bad.exit_code == 1
    assert "422" in bad.stderr and "key=value" in bad.stderr


def test_an_unreachable_server_is_one_line_too():
    done = runner.invoke(app, ["jobs"], env={"ROADLINK_URL": f"http://127.0.0.1:{free_port()}"})
    assert done.exit_code == 1
    assert done.stderr.startswith("error: cannot reach http://127.0.0.1:")

"""`roadlink keys create | list | revoke` (`cli/keys.py`), on a fresh SQLite database."""

import re
import uuid
from typing import Any

import pytest
from typer.testing import CliRunner

from roadlink.cli import app

runner = CliRunner()


def env(tmp_path):
    return {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 'keys.db'}"}


def test_an_unknown_deployment_or_key_is_an_error_naming_it(tmp_path):
    missing = uuid.uuid4()
    result = runner.invoke(
        app,
        ["keys", "create", "--scope", "ingest", "--deployment", str(missing)],
        env=env(tmp_path),
    )
    assert result.exit_code == 2 and f"there is no deployment {missing}" in result.stderr
    result = runner.invoke(app, ["keys", "revoke", "rl_nothing"], env=env(tmp_path))
    assert result.exit_code == 2 and "there is no API key rl_nothing" in result.stderr


def test_no_keys_says_how_to_create_one(tmp_path):
    runner.invoke(app, ["migrate"], env=env(tmp_path))
    result = runner.invoke(app, ["keys", "list"], env=env(tmp_path))
    assert result.exit_code == 0 and result.stdout == ""
    assert "roadlink keys create --scope admin" in result.stderr


def test_keys_cli_creates_lists_and_revokes(monkeypatch: pytest.MonkeyPatch, tmp_path: Any) -> None:
    monkeypatch.setenv("ROADLINK_DATABASE_URL", f"sqlite:///{tmp_path / 'keys.db'}")
    admin = runner.invoke(app, ["keys", "create", "--scope", "admin", "--name", "ops"])
    assert admin.exit_code == 0, admin.output
    key = admin.stdout.strip()
    assert re.fullmatch(r"rl_[0-9a-f]{8}_[A-Za-z0-9_-]{43}", key)
    assert "only time it is shown" in admin.stderr
    no_deployment = runner.invoke(app, ["keys", "create", "--scope", "ingest"])
    assert no_deployment.exit_code == 2 and "at least one deployment" in no_deployment.stderr
    unknown = runner.invoke(
        app, ["keys", "create", "--scope", "ingest", "--deployment", str(uuid.uuid4())]
    )
    assert unknown.exit_code == 2 and "there is no deployment" in unknown.stderr
    listed = runner.invoke(app, ["keys", "list"])
    assert listed.exit_code == 0
    assert key.split("_")[1] in listed.stdout and "ops" in listed.stdout
    assert key not in listed.stdout and key.split("_", 2)[2] not in listed.stdout
    key_id = listed.stdout.splitlines()[1].split("\t")[0]
    assert runner.invoke(app, ["keys", "revoke", key_id]).exit_code == 0
    assert "already revoked" in runner.invoke(app, ["keys", "revoke", key_id]).stdout
    assert key.split("_")[1] not in runner.invoke(app, ["keys", "list"]).output
    assert key.split("_")[1] in runner.invoke(app, ["keys", "list", "--all"]).stdout

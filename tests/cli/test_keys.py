"""`roadlink keys create | list | revoke` (`cli/keys.py`), on a fresh SQLite database."""

import uuid

from typer.testing import CliRunner

from roadlink.cli import app

runner = CliRunner()


def env(tmp_path):
    return {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 'keys.db'}"}


def test_a_key_is_created_listed_by_prefix_only_and_revoked_once(tmp_path):
    created = runner.invoke(
        app, ["keys", "create", "--scope", "admin", "--name", "ops"], env=env(tmp_path)
    )
    assert created.exit_code == 0, created.stderr
    key = created.stdout.strip()
    assert key and "\n" not in key
    assert "this is the only time it is shown" in created.stderr

    listed = runner.invoke(app, ["keys", "list"], env=env(tmp_path))
    assert listed.exit_code == 0, listed.stderr
    header, row = listed.stdout.strip().split("\n")
    assert header == "id\tprefix\tscope\tdeployments\tname\tcreated\trevoked"
    key_id, prefix, scope, deployments, name, _, revoked = row.split("\t")
    assert (scope, deployments, name, revoked) == ("admin", "-", "ops", "-")
    assert key.startswith(f"rl_{prefix}_")
    assert key not in listed.stdout  # never the secret

    first = runner.invoke(app, ["keys", "revoke", prefix], env=env(tmp_path))
    assert first.exit_code == 0 and first.stdout.startswith(f"revoked admin key {prefix}")
    again = runner.invoke(app, ["keys", "revoke", key_id], env=env(tmp_path))
    assert again.exit_code == 0 and again.stdout.strip().endswith("was already revoked")
    assert runner.invoke(app, ["keys", "list"], env=env(tmp_path)).stdout == ""
    shown = runner.invoke(app, ["keys", "list", "--all"], env=env(tmp_path)).stdout
    assert shown.strip().split("\n")[1].split("\t")[-1] != "-"


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

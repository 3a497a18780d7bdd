"""Settings (`settings.py`): read only from ROADLINK_* variables, frozen, checked as a whole
(a heartbeat within the lease), and an empty public URL is no public URL. (Every setting's
documentation, generated from these: test_configuration.py.)"""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from roadlink.settings import Settings


def test_settings_come_from_roadlink_variables_only(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROADLINK_PORT", "9000")
    monkeypatch.setenv("ROADLINK_AUTH", "disabled")
    monkeypatch.setenv("PORT", "1")  # another program's: ignored
    monkeypatch.setenv("ROADLINK_NO_SUCH_SETTING", "x")  # unknown: ignored, not an error
    settings = Settings()
    assert (settings.port, settings.auth) == (9000, "disabled")
    with pytest.raises(ValidationError):
        settings.port = 1  # type: ignore[misc]


@pytest.mark.parametrize(
    ("variable", "value", "message"),
    [
        ("ROADLINK_PORT", "70000", "less than or equal to 65535"),
        ("ROADLINK_AUTH", "maybe", "'required' or 'disabled'"),
        ("ROADLINK_IDEMPOTENCY_HOURS", "1", "greater than or equal to 24"),
        ("ROADLINK_PUBLIC_URL", "roadlink.example", "should match pattern"),
        ("ROADLINK_HEARTBEAT_SECONDS", "30", "must be shorter than ROADLINK_LEASE_SECONDS"),
    ],
)
def test_a_bad_value_is_refused_naming_what_is_wrong(
    monkeypatch: pytest.MonkeyPatch, variable: str, value: str, message: str
) -> None:
    monkeypatch.setenv("ROADLINK_LEASE_SECONDS", "30")
    monkeypatch.setenv(variable, value)
    with pytest.raises(ValidationError, match=message):
        Settings()


def test_an_empty_public_url_is_unset_and_a_full_one_is_kept(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv("ROADLINK_PUBLIC_URL", "")
    assert Settings().public_url is None
    monkeypatch.setenv("ROADLINK_PUBLIC_URL", "https://roadlink.example/base")
    assert Settings().public_url == "https://roadlink.example/base"

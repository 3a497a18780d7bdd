"""Which URLs a webhook may have, refused as a 422 naming `url` (the routes over it:
tests/api/routers/test_webhooks.py)."""

from __future__ import annotations

import pytest

from roadlink.services.problems import ServiceProblem
from roadlink.services.webhooks import check_url


@pytest.mark.parametrize(
    "url",
    [
        "https://hooks.example/roadlink?x=1",
        "http://127.0.0.1:8080/x",
        "http://127.9.9.9/",
        "http://LOCALHOST/x",
        "http://[::1]:9/",
    ],
)
def test_https_anywhere_and_plain_http_to_loopback_are_taken_as_given(url: str) -> None:
    assert check_url(url, allow_http=False) == url


@pytest.mark.parametrize(
    ("url", "says"),
    [
        ("http://10.0.0.1/x", "must be https://"),
        ("http://localhost.example/x", "must be https://"),
        ("mailto:ops@example.org", "absolute https:// URL"),
        ("https://:pw@hooks.example/", "credentials"),
    ],
)
def test_other_urls_are_a_422_naming_url(url: str, says: str) -> None:
    with pytest.raises(ServiceProblem) as refused:
        check_url(url, allow_http=False)
    assert refused.value.status == 422 and says in refused.value.detail
    assert [e.field for e in refused.value.errors] == ["url"]


def test_roadlink_webhook_allow_http_accepts_plain_http_to_any_host() -> None:
    assert check_url("http://hooks.example/x", allow_http=True) == "http://hooks.example/x"
    with pytest.raises(ServiceProblem):
        check_url("http://hooks.example/x", allow_http=False)

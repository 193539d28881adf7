"""The credentials a hostile page or client attacks (server/security.py, docs/security.md),
against a real uvicorn: a viewer secret that cannot be empty or raced, an empty cookie that
matches nothing, a throttle a page cannot turn against the rightful clients and no client can
bypass by its source address. Each test names the mutation it guards.
"""

from __future__ import annotations

import asyncio
import dataclasses
import os
import stat
import threading
from pathlib import Path

import pytest

from gazehdr.security import (
    FAILURE_BURST,
    SECRET_FILE,
    Answer,
    Guard,
    SecretError,
    cookie_secret,
    policy_for,
    throttle_key,
)
from tests.test_security import request, ws_close

#: What Chromium sends for `<img src="http://127.0.0.1:PORT/?token=x">` on another site's page.
EMBEDDED = {"sec-fetch-site": "cross-site", "sec-fetch-mode": "no-cors", "sec-fetch-dest": "image"}
#: And for a link on another site's page that the user follows (or a page navigates to).
NAVIGATED = {"sec-fetch-site": "cross-site", "sec-fetch-mode": "navigate",
             "sec-fetch-dest": "document"}  # fmt: skip


def test_an_empty_or_short_or_readable_secret_is_refused_at_start(tmp_path: Path) -> None:
    """A viewer-secret left empty (a full disk, a crash while it was written) or truncated, or
    readable by other users, stops the server at start with what to do. Guards the read-back
    check (an empty secret made `Cookie: gazehdr-PORT=` pass)."""
    path = tmp_path / SECRET_FILE
    for text, why in (("", "no usable secret"), ("abc\n", "no usable secret"),
                      ("x" * 40 + "!\n", "no usable secret")):  # fmt: skip
        path.write_text(text)
        path.chmod(0o600)
        with pytest.raises(SecretError, match=why) as e:
            cookie_secret(tmp_path)
        assert "delete it" in str(e.value)
    path.write_text("a" * 43 + "\n")
    path.chmod(0o644)
    with pytest.raises(SecretError, match="can be read by other users"):
        cookie_secret(tmp_path)


def test_servers_starting_at_once_agree_on_one_whole_secret(tmp_path: Path) -> None:
    """Forty first starts at once on one data directory: every one reads the same secret of
    full length, and the file is private. Guards the write-then-link (a file created, then
    written, was read empty by 172 of 1,000 concurrent starts)."""
    for attempt in range(5):
        folder = tmp_path / f"d{attempt}"
        got: list[str | Exception] = []
        start = threading.Barrier(40)

        def first_start(folder: Path = folder, got: list = got, start=start) -> None:
            start.wait()
            try:
                got.append(cookie_secret(folder))
            except Exception as e:  # any failure is the finding
                got.append(e)

        threads = [threading.Thread(target=first_start) for _ in range(40)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(set(map(str, got))) == 1 and len(str(got[0])) == 43, got[:3]
        assert stat.S_IMODE(os.stat(folder / SECRET_FILE).st_mode) == 0o600
        assert [p.name for p in folder.iterdir()] == [SECRET_FILE]  # no temporary left


def test_an_empty_cookie_matches_nothing(live_server) -> None:
    """`Cookie: gazehdr-PORT=` (empty) is refused on writes, private reads and both
    WebSockets, on a real server and by a guard whose secret is empty (what a server that read
    an empty file had). Guards the emptiness check of the comparison."""
    server = live_server(token="tok")
    empty = {"cookie": f"gazehdr-{server.port}="}
    assert request(server, "PUT", "/api/params", b"{}", **empty)[0] == 401
    assert request(server, "GET", "/api/recordings", **empty)[0] == 401
    for path in ("/ws/view", "/ws/gaze"):
        code, _ = asyncio.run(ws_close(server.ws_url + path, additional_headers=empty))
        assert code == 4401, path
    guard = Guard(
        None, dataclasses.replace(policy_for(server.config), cookie_secret=""), lambda p: ["GET"]
    )
    scope = {"type": "http", "path": "/api/recordings", "method": "GET", "headers": [],
             "client": ("127.0.0.1", 5), "query_string": b""}  # fmt: skip
    headers = {"host": f"127.0.0.1:{server.port}", "cookie": f"gazehdr-{server.port}="}
    with pytest.raises(Answer) as refused:
        guard.check(scope, headers, websocket=False)
    assert refused.value.status == 401


def test_throttle_keys_group_a_hosts_addresses() -> None:
    """One key for all of loopback (a local process can send from any 127.x), one per IPv6
    /64, one per IPv4 address. Guards the grouping (a key per address let 1000 guesses from
    rotating 127.0.x.y addresses through in 2.25 s)."""
    assert {throttle_key(a) for a in ("127.0.0.1", "127.0.3.4", "::1", "::ffff:127.0.0.9")} == {
        "loopback"
    }
    assert throttle_key("2001:db8::1") == throttle_key("2001:db8::ffff:2") == "2001:db8::/64"
    assert throttle_key("2001:db8:0:1::1") != throttle_key("2001:db8::1")
    assert throttle_key("192.0.2.1") != throttle_key("192.0.2.2")


def test_guesses_from_rotating_addresses_or_forwarded_headers_are_throttled_as_one(
    live_server,
) -> None:
    """Bearer guesses from 127.0.0.2, .3, ... each with another X-Forwarded-For: the burst
    allowed one address, then 429 for the next, whatever address or header. Guards the
    loopback grouping and uvicorn's proxy headers off (it believed X-Forwarded-For from
    127.0.0.1)."""
    server = live_server(token="tok")
    answers = [  # every other one from 127.0.0.1, whose forwarded headers uvicorn believed
        request(server, "GET", "/api/recordings",
                source="127.0.0.1" if i % 2 else f"127.0.{i // 200}.{2 + i % 200}",
                authorization="Bearer guess", **{"x-forwarded-for": f"198.51.100.{i}"})[0]
        for i in range(int(FAILURE_BURST) + 6)
    ]  # fmt: skip
    assert answers[: int(FAILURE_BURST)] == [401] * int(FAILURE_BURST)
    assert set(answers[int(FAILURE_BURST) :]) == {429}


def test_a_page_cannot_lock_out_the_viewer_or_the_daemon(live_server) -> None:
    """Another site's page makes the browser try `/?token=` many times (images, then
    navigations): embedded requests are refused untried, navigations count against a throttle
    of their own. The viewer's cookie, the daemon's bearer token and someone typing the
    address with the token are never held back by them. Guards the page's own throttle (one
    per address: ten images locked out every loopback client) and the untried refusal."""
    server = live_server(token="tok")
    cookie = request(server, "GET", "/")[1]["set-cookie"].split(";")[0]
    for _ in range(3 * int(FAILURE_BURST)):
        status, _, answer = request(server, "GET", "/?token=guess", **EMBEDDED)
        assert status == 403 and "another site" in answer["detail"]
    navigated = [request(server, "GET", "/?token=guess", **NAVIGATED)[0] for _ in range(12)]
    assert navigated == [401] * int(FAILURE_BURST) + [429] * (12 - int(FAILURE_BURST))
    assert request(server, "GET", "/api/recordings", cookie=cookie)[0] == 200
    assert request(server, "GET", "/api/recordings", **server.auth)[0] == 200
    typed = request(server, "GET", "/?token=tok", **{"sec-fetch-site": "none"})
    assert typed[0] == 303 and typed[1]["set-cookie"].startswith(cookie)
    # the right token from the page's navigation waits with its guesses (no oracle)
    assert request(server, "GET", "/?token=tok", **NAVIGATED)[0] == 429


# --- what a mutation audit left alive: each test names its mutant ------------------------------


def _guard(server) -> Guard:
    return Guard(None, policy_for(server.config), lambda path: ["GET", "HEAD", "PUT"])


def _scope(path: str, client: str) -> dict:
    return {"type": "http", "path": path, "method": "GET", "headers": [], "query_string": b"",
            "client": (client, 40000), "server": ("127.0.0.1", 8000)}  # fmt: skip


def test_a_loopback_bound_server_refuses_an_ip_literal_host(live_server) -> None:
    """An IP literal is a Host of a wildcard-bound server only: bound to 127.0.0.1, a request
    naming 192.0.2.1 (a rebinding page could use any address) is refused. Mutant: any IP
    literal accepted whatever the binding (`any_ip` ignored)."""
    server = live_server(token="tok")
    for host in ("192.0.2.1", "[2001:db8::1]", f"10.0.0.1:{server.port}"):
        assert request(server, "GET", "/api/health", host=host)[0] == 421, host
    assert request(server, "GET", "/api/health", host=f"127.0.0.1:{server.port}")[0] == 200


def test_an_origin_on_another_port_of_this_host_is_foreign(live_server) -> None:
    """SameSite ignores ports, so a page served from another port of this machine gets the
    viewer's cookie sent with its requests; its Origin, which names that port, is refused.
    Mutant: Origin compared by host name only."""
    server = live_server(token="tok")
    cookie = request(server, "GET", "/")[1]["set-cookie"].split(";")[0]
    other = f"http://127.0.0.1:{server.port + 1 if server.port < 65535 else server.port - 1}"
    status, _, answer = request(server, "PUT", "/api/params", b"{}", origin=other, cookie=cookie,
                                **{"content-type": "application/json"})  # fmt: skip
    assert status == 403 and "origin" in answer["detail"]
    same = request(server, "PUT", "/api/params", b"{}", origin=server.url, cookie=cookie,
                   **{"content-type": "application/json"})  # fmt: skip
    assert same[0] == 200


def test_the_cookie_is_never_handed_to_a_client_on_the_network(live_server) -> None:
    """The viewer page gives its cookie to a loopback client only (or after the token): a
    client on the network that loads `/` gets the page and no cookie. Mutant: the loopback
    check dropped from _viewer_cookie."""
    server = live_server(token="tok")
    guard = _guard(server)
    headers = {"host": f"127.0.0.1:{server.port}"}
    assert guard.check(_scope("/", "192.0.2.9"), headers, websocket=False) is None
    given = guard.check(_scope("/", "127.0.0.1"), headers, websocket=False)
    assert given and given[0][0] == b"set-cookie"


def test_typed_token_guesses_in_the_address_are_throttled(live_server) -> None:
    """`/?token=` guesses typed into the address bar (no page of another site) count like
    bearer guesses: 10, then 429 whatever the guess. Mutant: the token in the address not
    throttled (a failure not counted, or the wait not checked)."""
    server = live_server(token="tok")
    typed = {"sec-fetch-site": "none", "sec-fetch-mode": "navigate"}
    answers = [request(server, "GET", f"/?token=guess{i}", **typed)[0] for i in range(12)]
    assert answers == [401] * int(FAILURE_BURST) + [429] * (12 - int(FAILURE_BURST))
    assert request(server, "GET", "/?token=tok", **typed)[0] == 429  # no oracle

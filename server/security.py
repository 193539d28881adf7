"""Who may talk to the server: Host, Origin, credentials, throttling, CORS and OPTIONS.

One ASGI middleware (`Guard`) sits in front of every route, HTTP and WebSocket, and applies, in
this order (docs/security.md explains why each is there):

1. **Host**: the name the client used must be one this server was started for (loopback names,
   the bound address, `--allow-host`); otherwise 421. This is what defeats DNS rebinding.
2. **OPTIONS** is answered here: `Allow` lists the route's real methods; a CORS preflight is
   answered only for an allowed origin, never with a wildcard. Other unknown methods: 405.
3. **Origin**: a browser request from another origin (not this server, not `--allow-origin`) is
   refused with 403 when it writes, reads private data, or opens a WebSocket (CSWSH).
4. **Credential** (`needs_credential`): the bearer token `serve` prints, or the viewer's cookie
   (set when a loopback client, or one that shows the token once as `/?token=`, loads the viewer
   page). Missing or wrong: 401; an address with too many wrong ones waits (429).

WebSockets are refused by accepting and closing at once with code 4000 + the HTTP status (4401,
4403, 4421, 4429) and the reason, which browsers and the daemon can read; HTTP refusals are
JSON `{"detail": reason}`, the one error shape of the API (`ERROR_SCHEMA`).
"""

from __future__ import annotations

import contextlib
import copy
import ipaddress
import json
import math
import os
import re
import secrets
import tempfile
import time
from collections import OrderedDict
from collections.abc import Awaitable, Callable, Hashable, MutableMapping
from dataclasses import dataclass
from http.cookies import CookieError, SimpleCookie
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from gazehdr.drivers.errors import InputError
from gazehdr.drivers.ratelimit import TokenBucket
from gazehdr.viewer import default_web_dir

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1")
WILDCARD_HOSTS = ("0.0.0.0", "::", "")
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
#: The routes anyone may read (GET, HEAD, OPTIONS), on purpose; with the viewer's static files,
#: nothing else: every other route, a new one too, needs a credential until it is listed here
#: (docs/security.md, "Adding a route"). Private, so not here: recordings (people's gaze),
#: sessions (their ids let one join and watch a session's gaze), an experiment's runs (an
#: observer's trials and answers) and its palette images.
PUBLIC_READS = (
    "/", "/index.html", "/experiment",  # the viewer's and the experiment's pages
    "/api/health", "/metrics",  # for monitors: counts, no gaze
    "/api/scenes", "/api/scenes/{name}", "/api/params",  # what a viewer shows and offers
    "/openapi.json", "/docs", "/docs/oauth2-redirect", "/redoc",  # the API's description
)  # fmt: skip
_PUBLIC = [re.compile(re.sub(r"\\\{\w+\\\}", "[^/]+", re.escape(p))) for p in PUBLIC_READS]
VIEWER_PAGES = ("/", "/index.html", "/experiment")
COOKIE_PREFIX = "gazehdr-"
SECRET_FILE = "viewer-secret"
SECRET_BYTES = 32  # the secret's entropy: token_urlsafe(32), 43 characters
SECRET_MIN_CHARS = 32  # fewer characters read back: truncated, refused
_SECRET_CHARS = re.compile(r"[A-Za-z0-9_-]+")
# Failed token attempts, per client (`throttle_key`) and way of trying: 10 at once, then one
# every 6 s (600 guesses an hour) until it stops failing for a minute. A weak --token is still
# weak; this makes guessing it slow.
FAILURE_BURST = 10.0
FAILURE_RATE = 1 / 6
MAX_CLIENTS = 4096  # addresses remembered; the oldest is forgotten first
ERROR_SCHEMA = {
    "title": "Error",
    "type": "object",
    "properties": {"detail": {"type": "string", "description": "what is wrong, for a person"}},
    "required": ["detail"],
}


class FailedLogins:
    """Per key (a client's `throttle_key` and the way it tried), a `TokenBucket` of failed
    authentications: each failure takes a token; a key with none left waits until the bucket
    refills. It reads no clock."""

    def __init__(
        self, rate: float = FAILURE_RATE, burst: float = FAILURE_BURST, limit: int = MAX_CLIENTS
    ) -> None:
        self.rate, self.burst, self.limit = rate, burst, limit
        self.buckets: OrderedDict[Hashable, TokenBucket] = OrderedDict()

    def wait(self, key: Hashable, now: float) -> float:
        """Seconds `key` must wait before its next attempt counts; 0 if it may try now."""
        bucket = self.buckets.get(key)
        if bucket is None or bucket.available(now) >= 1:
            return 0.0
        return (1 - bucket.level) / bucket.rate

    def failed(self, key: Hashable, now: float) -> None:
        bucket = self.buckets.pop(key, None) or TokenBucket(self.rate, self.burst)
        bucket.admit(1, now)
        self.buckets[key] = bucket  # most recent last
        while len(self.buckets) > self.limit:
            self.buckets.popitem(last=False)


@dataclass(frozen=True)
class Policy:
    """What `Guard` enforces; `policy_for(config)` builds it from the server's configuration."""

    auth: bool
    token: str
    cookie_secret: str
    hosts: frozenset[str]
    any_ip: bool  # bound to a wildcard address: any IP literal is a Host of this server
    origins: frozenset[str]
    public_files: frozenset[str] = frozenset()  # the viewer's static files, as "/main.js"

    def host_allowed(self, host: str | None) -> bool:
        name = host_name(host)
        if name is None:
            return False
        if name in self.hosts:
            return True
        if not self.any_ip:
            return False
        try:
            ipaddress.ip_address(name)
        except ValueError:
            return False
        return True  # an IP literal cannot be rebound to another server by DNS

    def origin_allowed(self, origin: str | None, host: str | None) -> bool:
        """No Origin: not a browser page, which cannot then be driven by a foreign one."""
        if origin is None:
            return True
        if origin in self.origins:
            return True
        parts = urlsplit(origin)
        return parts.scheme in ("http", "https") and host is not None and parts.netloc == host


def host_name(host: str | None) -> str | None:
    """The name in a Host header, lower case, without port or IPv6 brackets; None if bad."""
    if not host:
        return None
    try:
        parts = urlsplit(f"//{host}")
        parts.port  # noqa: B018 -- a bad port raises
    except ValueError:
        return None
    return parts.hostname or None


def policy_for(config: Any) -> Policy:
    """The policy of a `ServerConfig` (its host, token, data_dir, allow_hosts, allow_origins,
    auth)."""
    hosts = set(LOOPBACK_NAMES)
    bound = host_name(f"[{config.host}]" if ":" in config.host else config.host)
    if config.host not in WILDCARD_HOSTS and bound:
        hosts.add(bound)
    for name in config.allow_hosts:
        hosts.add(host_name(f"[{name}]" if name.count(":") > 1 else name) or name.lower())
    return Policy(
        auth=config.auth,
        token=config.token,
        cookie_secret=cookie_secret(config.data_dir),
        hosts=frozenset(hosts),
        any_ip=config.host in WILDCARD_HOSTS,
        origins=frozenset(o.rstrip("/") for o in config.allow_origins),
        public_files=static_files(config.web_dir or default_web_dir()),
    )


def static_files(web_dir: Path) -> frozenset[str]:
    """The viewer's files that anyone may read: what the web folder serves (its pages, scripts
    and styles), as URL paths."""
    kinds = (".html", ".js", ".css", ".png", ".svg", ".ico")
    return frozenset(f"/{f.name}" for f in Path(web_dir).iterdir() if f.suffix in kinds)


def cookie_secret(data_dir: Path | None) -> str:
    """The viewer cookie's secret: kept in DATA_DIR/viewer-secret (readable by this user only),
    so that a restarted server still knows the viewers its predecessor let in; new per run
    without a data directory. It is not the bearer token: a weak --token does not weaken it.
    The file is written whole under another name and linked into place, so that servers
    starting at once agree on one secret and none reads a half-written one; what is read is
    checked (`SecretError`): an empty, short or world-readable secret is never used."""
    if data_dir is None:
        return secrets.token_urlsafe(SECRET_BYTES)
    path = Path(data_dir) / SECRET_FILE
    if not path.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
        _write_secret(path)
    return _read_secret(path)


class SecretError(InputError):
    """The viewer secret on disk cannot be used; the message says why and what to do."""


def _write_secret(path: Path) -> None:
    """A new secret at `path`, unless another server put one there first (theirs stays)."""
    fd, temporary = tempfile.mkstemp(prefix=f".{SECRET_FILE}.", dir=path.parent)  # mode 0600
    try:
        with os.fdopen(fd, "w", encoding="ascii") as f:
            f.write(secrets.token_urlsafe(SECRET_BYTES) + "\n")
            f.flush()
            os.fsync(f.fileno())
        with contextlib.suppress(FileExistsError):  # another server's stays
            os.link(temporary, path)  # atomic, and fails if the name exists
    finally:
        os.unlink(temporary)


def _read_secret(path: Path) -> str:
    mode = path.stat().st_mode
    if mode & 0o077:
        raise SecretError(
            f"{path} can be read by other users (mode {mode & 0o777:o}): whoever reads it can "
            "sign in as a viewer; make it private (chmod 600) or delete it for a new one"
        )
    secret = path.read_text(encoding="ascii", errors="replace").strip()
    if len(secret) < SECRET_MIN_CHARS or not _SECRET_CHARS.fullmatch(secret):
        raise SecretError(
            f"{path} holds no usable secret ({len(secret)} characters; a full disk or a crash "
            f"while it was written?): delete it and start again to make a new one"
        )
    return secret


def needs_credential(
    method: str, path: str, websocket: bool = False, files: frozenset[str] = frozenset()
) -> bool:
    """The one rule: a credential for everything but reading what is public on purpose, a
    route of PUBLIC_READS or one of the viewer's static `files` (paths as "/main.js")."""
    if websocket or method not in SAFE_METHODS:
        return True
    return path not in files and not any(p.fullmatch(path) for p in _PUBLIC)


def _headers(scope: Scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}


class Answer(Exception):  # noqa: N818 -- a refusal, or a 204 or 303 answered here
    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(detail)
        self.status, self.detail, self.headers = status, detail, headers or {}


class Guard:
    """The middleware; `methods(path)` names the methods the app serves at `path`."""

    def __init__(
        self,
        app: ASGIApp,
        policy: Policy,
        methods: Callable[[str], list[str]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.app, self.policy, self.methods, self.clock = app, policy, methods, clock
        self.failures = FailedLogins()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        websocket = scope["type"] == "websocket"
        headers = _headers(scope)
        try:
            extra = self.check(scope, headers, websocket)
        except Answer as r:
            if websocket:
                return await _close(receive, send, 4000 + r.status, r.detail)
            return await _respond(send, r.status, {"detail": r.detail}, r.headers)
        if extra is None:
            return await self.app(scope, receive, send)

        async def send_with(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await self.app(scope, receive, send_with)

    def check(
        self, scope: Scope, headers: dict[str, str], websocket: bool
    ) -> list[tuple[bytes, bytes]] | None:
        """Answer, or the headers to add to the answer (None: none)."""
        host, origin = headers.get("host"), headers.get("origin")
        path, method = scope["path"], "GET" if websocket else scope["method"]
        if not self.policy.host_allowed(host):
            raise Answer(
                421,
                f"host {host!r} is not a name of this server"
                + ("" if websocket else "; start it with --allow-host NAME to add one"),
            )
        allowed = [] if websocket else self.methods(path)
        if method == "OPTIONS":
            raise self._options(allowed, origin, host, headers)
        if not websocket and method not in allowed:
            raise Answer(405, f"{method} is not allowed here", {"allow": ", ".join(allowed)})
        private = needs_credential(method, path, websocket, self.policy.public_files)
        if (private or method not in SAFE_METHODS) and not self.policy.origin_allowed(origin, host):
            raise Answer(403, f"origin {origin} is not allowed")
        extra: list[tuple[bytes, bytes]] = []
        if origin is not None and origin in self.policy.origins:
            extra += _cors(origin)
        if self.policy.auth:
            if private:
                self._authenticate(scope, headers, websocket)
            elif path in VIEWER_PAGES and method in ("GET", "HEAD"):
                extra += self._viewer_cookie(scope, headers)
        return extra or None

    def _options(
        self, allowed: list[str], origin: str | None, host: str | None, headers: dict[str, str]
    ) -> Answer:
        """The answer to OPTIONS, as a Answer carrying 204 (a preflight or not)."""
        allow = ", ".join(allowed)
        if origin is None or "access-control-request-method" not in headers:
            return Answer(204, "", {"allow": allow})
        if not self.policy.origin_allowed(origin, host):
            return Answer(403, f"origin {origin} is not allowed")
        cors = {k.decode(): v.decode() for k, v in _cors(origin)}
        return Answer(
            204,
            "",
            {
                "allow": allow,
                **cors,
                "access-control-allow-methods": allow,
                "access-control-allow-headers": "Authorization, Content-Type",
                "access-control-max-age": "600",
            },
        )

    def _authenticate(self, scope: Scope, headers: dict[str, str], websocket: bool) -> None:
        """The bearer token, or the viewer's cookie. Wrong tokens are throttled per client
        (`throttle_key`); cookies are not: the secret (256 bits) is not worth guessing, and a
        viewer holding it is never refused because of others' failures."""
        client = (scope.get("client") or ("unknown", 0))[0]
        given = headers.get("authorization")
        cookie = _cookie(headers, self._cookie_name(scope, headers))
        if given is None and cookie is not None:
            if cookie and secrets.compare_digest(
                cookie.encode(), self.policy.cookie_secret.encode()
            ):
                return
            raise Answer(
                401,
                "unauthorized: wrong cookie",
                {"www-authenticate": 'Bearer realm="gazehdr", error="invalid_token"'},
            )
        if given is None:
            raise Answer(
                401,
                "unauthorized: missing bearer token"
                + ("" if websocket else "; send Authorization: Bearer TOKEN (serve prints it)"),
                {"www-authenticate": 'Bearer realm="gazehdr"'},
            )
        expected = f"Bearer {self.policy.token}"
        key = (throttle_key(client), "token")
        self._check_token(client, key, given, expected, "bearer token")

    def _check_token(
        self, client: str, key: tuple[str, str], given: str, expected: str, what: str
    ) -> None:
        """Compare a token attempt, unless its throttle says wait; count it if wrong."""
        now = self.clock()
        wait = self.failures.wait(key, now)
        if wait > 0:
            raise Answer(
                429,
                f"too many failed authentications from {client}; wait {math.ceil(wait)} s",
                {"retry-after": str(math.ceil(wait))},
            )
        if not (given and secrets.compare_digest(given.encode(), expected.encode())):
            self.failures.failed(key, now)
            raise Answer(
                401,
                f"unauthorized: wrong {what}",
                {"www-authenticate": 'Bearer realm="gazehdr", error="invalid_token"'},
            )

    def _viewer_cookie(self, scope: Scope, headers: dict[str, str]) -> list[tuple[bytes, bytes]]:
        """The viewer page gives the browser its credential: to a loopback client, or to one
        that shows the token once (`/?token=TOKEN`, then redirected to drop it from the URL).
        A page of another site cannot make the browser try tokens here to lock the rightful
        clients out: an embedded request (an image, a script, a fetch) is refused untried,
        and a navigation from there counts against a throttle of its own, never the one of
        the daemon's bearer token or of someone typing the address."""
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        client = (scope.get("client") or ("", 0))[0]
        if "token" in query:
            page = _from_another_page(headers, self.policy)
            if page and headers.get("sec-fetch-mode", "navigate") != "navigate":
                raise Answer(403, "a page of another site cannot sign in with the token")
            key = (throttle_key(client), "page" if page else "token")
            given = query["token"][-1]
            self._check_token(client, key, given, self.policy.token, "token in the address")
            raise Answer(
                303, "", {"location": scope["path"], "set-cookie": self._set_cookie(scope, headers)}
            )
        if not _loopback(client):
            return []
        return [(b"set-cookie", self._set_cookie(scope, headers).encode("latin-1"))]

    def _cookie_name(self, scope: Scope, headers: dict[str, str]) -> str:
        """Cookies ignore ports: one name per port keeps two servers on one host apart."""
        try:
            port = urlsplit(f"//{headers.get('host', '')}").port
        except ValueError:
            port = None
        return f"{COOKIE_PREFIX}{port or (scope.get('server') or ('', 80))[1]}"

    def _set_cookie(self, scope: Scope, headers: dict[str, str]) -> str:
        name = self._cookie_name(scope, headers)
        return f"{name}={self.policy.cookie_secret}; Path=/; HttpOnly; SameSite=Strict"


def throttle_key(client: str) -> str:
    """The clients that share a throttle: one per address, but all of loopback as one (a local
    process may send from any of 127.0.0.0/8 and ::1) and an IPv6 address by its /64 (one host
    has many), so that changing the source address does not buy more guesses."""
    try:
        ip = ipaddress.ip_address(client)
    except ValueError:
        return client
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    if ip.is_loopback:
        return "loopback"
    if isinstance(ip, ipaddress.IPv6Address):
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


def _from_another_page(headers: dict[str, str], policy: Policy) -> bool:
    """Whether a browser sent this for a page of another origin: its fetch metadata says so
    (`Sec-Fetch-Site`: cross-site, or same-site: another port of this host), or its Origin is
    not this server's."""
    if headers.get("sec-fetch-site") in ("cross-site", "same-site"):
        return True
    return not policy.origin_allowed(headers.get("origin"), headers.get("host"))


def _loopback(client: str) -> bool:
    try:
        return ipaddress.ip_address(client).is_loopback
    except ValueError:
        return False


def _cookie(headers: dict[str, str], name: str) -> str | None:
    raw = headers.get("cookie")
    if not raw:
        return None
    jar: SimpleCookie = SimpleCookie()
    try:
        jar.load(raw)
    except CookieError:
        return None
    morsel = jar.get(name)
    return None if morsel is None else morsel.value


def _cors(origin: str) -> list[tuple[bytes, bytes]]:
    return [
        (b"access-control-allow-origin", origin.encode("latin-1")),
        (b"access-control-allow-credentials", b"true"),
        (b"vary", b"Origin"),
    ]


async def _respond(send: Send, status: int, body: dict[str, str], headers: dict[str, str]) -> None:
    raw = b"" if status in (204, 303) else json.dumps(body).encode()
    out = [(k.encode("latin-1"), v.encode("latin-1")) for k, v in headers.items()]
    if raw:
        out += [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(raw))]
    else:
        out.append((b"content-length", b"0"))
    await send({"type": "http.response.start", "status": status, "headers": out})
    await send({"type": "http.response.body", "body": raw})


async def _close(receive: Receive, send: Send, code: int, reason: str) -> None:
    """Accept and close at once: a browser sees the code and reason (a refused handshake
    shows it only 1006), and the daemon stops on 4401 instead of retrying."""
    message = await receive()
    if message["type"] != "websocket.connect":
        return
    await send({"type": "websocket.accept"})
    await send(
        {
            "type": "websocket.close",
            "code": code,
            "reason": reason.encode()[:123].decode("utf-8", "ignore"),
        }
    )


# --- installing it, and the OpenAPI description of what it does --------------------------------


def install(app: Any, config: Any) -> Policy:
    """Put the Guard in front of `app` and describe it in the app's OpenAPI document."""
    from fastapi.routing import APIRoute

    def methods(path: str) -> list[str]:
        found: set[str] = set()
        for route in app.router.routes:
            if isinstance(route, APIRoute) and route.path_regex.match(path):
                found |= route.methods
        if not found:  # the viewer's static files
            found = {"GET", "HEAD"}
        return sorted(found | {"OPTIONS"})

    policy = policy_for(config)
    app.add_middleware(Guard, policy=policy, methods=methods)
    base = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = describe(copy.deepcopy(base()), policy)
        return app.openapi_schema

    app.openapi = openapi
    return policy


def describe(schema: dict[str, Any], policy: Policy) -> dict[str, Any]:
    """Add to FastAPI's schema what the Guard does: auth, and its refusals in the one shape."""
    components = schema.setdefault("components", {})
    components.setdefault("schemas", {})["Error"] = ERROR_SCHEMA
    components["schemas"].pop("HTTPValidationError", None)
    components["schemas"].pop("ValidationError", None)
    components["securitySchemes"] = {
        "bearer": {
            "type": "http",
            "scheme": "bearer",
            "description": "the token `gazehdr serve` prints (`--token`, $GAZEHDR_TOKEN)",
        },
        "cookie": {
            "type": "apiKey",
            "in": "cookie",
            "name": f"{COOKIE_PREFIX}PORT",
            "description": "HttpOnly, SameSite=Strict; set by the viewer page (docs/security.md)"
            "; its name ends in the port of the address the browser used",
        },
    }

    def error(why: str) -> dict[str, Any]:
        ref = {"$ref": "#/components/schemas/Error"}
        return {"description": why, "content": {"application/json": {"schema": ref}}}

    for path, operations in schema.get("paths", {}).items():
        for method, op in operations.items():
            responses = op.setdefault("responses", {})
            for status, answer in responses.items():
                if status.startswith(("4", "5")):
                    answer["content"] = error(answer.get("description", ""))["content"]
            responses["421"] = error("the Host is not a name of this server")
            responses["405"] = error("method not allowed (the Allow header lists those that are)")
            write = method.upper() not in SAFE_METHODS
            private = needs_credential(method.upper(), path, files=policy.public_files)
            if private or write:
                responses["403"] = error("a browser page of another origin")
            if policy.auth and private:
                op["security"] = [{"bearer": []}, {"cookie": []}]
                responses["401"] = error("missing or wrong credential")
                responses["429"] = error("too many failed authentications from this address")
    return schema

"""Who may use a network output (web view, Foxglove): a cap, Host, Origin and a token.

The same rules for both servers, checked on a connection's HTTP request head
before anything is served or upgraded:

- **cap**: at most ``max_connections`` at a time; one more is answered 503
  and closed at once, so a flood of connections never takes the daemon's
  descriptors (nor its reopening of a replugged receiver);
- **Host** (DNS rebinding: a page of ``evil.example`` whose name turns into
  127.0.0.1 reaches a local server with ``Host: evil.example``): an IP
  literal, a localhost name, the name the server is bound to, or one of
  ``allowed_hosts`` (``*``: any);
- **Origin** (a browser's page reading a stream it was not served from):
  none (not a browser), the server's own (same host and port as ``Host``),
  or one of ``allowed_origins``;
- **token** (when one is set): ``?token=``, ``Authorization: Bearer``, or the
  cookie the web view sets once its page was opened with the token; compared
  in constant time.

Refusals are counted by reason and logged once per burst (``RefusalLog``),
never once per connection: a flood makes a line every ``BURST_LOG_S``, not
one per attempt.

Standard library only: the servers' own process (``front.py``) imports it.
"""

from __future__ import annotations

import dataclasses
import hmac
import ipaddress
import logging
import time
import urllib.parse
from collections.abc import Callable, Mapping, Sequence
from typing import Final

log = logging.getLogger(__name__)

BURST_LOG_S: Final = 10.0  # refusals are summed into one line at most this often
HEAD_LIMIT: Final = 16 * 1024  # a request head longer than this is refused
TOKEN_COOKIE: Final = "scotti_token"
LOCAL_NAMES: Final = ("localhost", "localhost.localdomain", "ip6-localhost")
WILDCARDS: Final = ("", "0.0.0.0", "::")  # bound everywhere: no name of its own

# Refusal reasons, the keys of the counters (and of the log line).
OVER_CAP: Final = "over_cap"
NO_DESCRIPTORS: Final = "no_descriptors"
BAD_REQUEST: Final = "bad_request"
HOST: Final = "host"
ORIGIN: Final = "origin"
TOKEN: Final = "token"
REASONS: Final = (OVER_CAP, NO_DESCRIPTORS, BAD_REQUEST, HOST, ORIGIN, TOKEN)
ANSWERS: Final[Mapping[str, str]] = {
    OVER_CAP: "503 Service Unavailable",
    BAD_REQUEST: "400 Bad Request",
    HOST: "403 Forbidden",
    ORIGIN: "403 Forbidden",
    TOKEN: "401 Unauthorized",
}
WHY: Final[Mapping[str, str]] = {
    OVER_CAP: "over the cap",
    NO_DESCRIPTORS: "no descriptor left",
    BAD_REQUEST: "bad request",
    HOST: "Host not allowed",
    ORIGIN: "Origin not allowed",
    TOKEN: "no or wrong token",
}


@dataclasses.dataclass(frozen=True, slots=True)
class Rules:
    """What a server lets in (``OutputSettings``' values, passed to the server's process)."""

    max_connections: int = 64
    bound_host: str = "127.0.0.1"
    allowed_hosts: Sequence[str] = ()
    allowed_origins: Sequence[str] = ()
    token: str | None = None


@dataclasses.dataclass(frozen=True, slots=True)
class Request:
    """The parts of a request head the rules and the routes look at."""

    method: str
    path: str  # unquoted, without the query
    query: Mapping[str, str]
    headers: Mapping[str, str]  # lower-case names; a repeated header keeps its last value

    @property
    def cookies(self) -> dict[str, str]:
        out = {}
        for part in self.headers.get("cookie", "").split(";"):
            name, eq, value = part.strip().partition("=")
            if eq:
                out[name] = value
        return out


def parse_head(head: bytes) -> Request | None:
    """``None`` for anything that is not an HTTP/1.x request head."""
    try:
        lines = head.decode("latin-1").split("\r\n")
        method, target, version = lines[0].split(" ")
    except ValueError:
        return None
    if not version.startswith("HTTP/1."):
        return None
    headers = {}
    for line in lines[1:]:
        if not line:
            continue
        name, colon, value = line.partition(":")
        if not colon:
            return None
        headers[name.strip().lower()] = value.strip()
    raw_path, _, raw_query = target.partition("?")
    query = dict(urllib.parse.parse_qsl(raw_query, keep_blank_values=True))
    return Request(method, urllib.parse.unquote(raw_path), query, headers)


def host_name(netloc: str) -> str:
    """``[::1]:8080`` -> ``::1``, ``Example.COM:80`` -> ``example.com``."""
    netloc = netloc.strip().lower()
    if netloc.startswith("["):
        return netloc[1:].partition("]")[0]
    return netloc.rpartition(":")[0] if netloc.count(":") == 1 else netloc


def host_allowed(netloc: str, rules: Rules) -> bool:
    name = host_name(netloc)
    if not name:
        return False
    if "*" in rules.allowed_hosts:
        return True
    try:
        ipaddress.ip_address(name)
    except ValueError:
        pass
    else:
        return True  # rebinding needs a name: an address typed by the user is theirs
    if name in LOCAL_NAMES or name.endswith(".localhost"):
        return True
    if rules.bound_host not in WILDCARDS and name == rules.bound_host.lower():
        return True
    return name in (h.lower() for h in rules.allowed_hosts)


def origin_allowed(origin: str | None, host: str, rules: Rules) -> bool:
    if origin is None:
        return True  # not a browser: Origin is what a page cannot leave out
    origin = origin.strip().rstrip("/").lower()
    if "*" in rules.allowed_origins or origin in (o.lower() for o in rules.allowed_origins):
        return True
    parts = urllib.parse.urlsplit(origin)
    return bool(parts.netloc) and parts.netloc == host.strip().lower()  # same origin


def token_of(request: Request) -> str | None:
    if "token" in request.query:
        return request.query["token"]
    bearer = request.headers.get("authorization", "")
    if bearer[:7].lower() == "bearer ":
        return bearer[7:].strip()
    return request.cookies.get(TOKEN_COOKIE)


def token_matches(given: str | None, token: str) -> bool:
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def refusal(request: Request | None, rules: Rules) -> str | None:
    """Why ``request`` is refused (a key of ``REASONS``), ``None`` when it may go on."""
    if request is None or "host" not in request.headers:
        return BAD_REQUEST
    host = request.headers["host"]
    if not host_allowed(host, rules):
        return HOST
    if not origin_allowed(request.headers.get("origin"), host, rules):
        return ORIGIN
    if rules.token is not None and not token_matches(token_of(request), rules.token):
        return TOKEN
    return None


def answer(reason: str) -> bytes:
    """The whole reply to a refused connection."""
    status = ANSWERS.get(reason, "503 Service Unavailable")
    body = f"{WHY.get(reason, reason)}\n".encode()
    extra = "Retry-After: 5\r\n" if reason == OVER_CAP else ""
    head = (
        f"HTTP/1.1 {status}\r\nContent-Type: text/plain\r\nContent-Length: {len(body)}\r\n"
        f"{extra}Cache-Control: no-store\r\nConnection: close\r\n\r\n"
    )
    return head.encode() + body


class RefusalLog:
    """Counts refusals by reason; logs the first of a burst at once and the rest summed,
    one line per ``BURST_LOG_S`` at most (``later`` schedules the summing line: the
    event loop's ``call_later``)."""

    def __init__(
        self,
        name: str,
        rules: Rules,
        later: Callable[[float, Callable[[], None]], object],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.name = name
        self.rules = rules
        self.counts: dict[str, int] = dict.fromkeys(REASONS, 0)
        self._later = later
        self._clock = clock
        self._logged_at = float("-inf")
        self._unlogged: dict[str, int] = {}
        self._pending = False

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def refused(self, reason: str) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        self._unlogged[reason] = self._unlogged.get(reason, 0) + 1
        wait = self._logged_at + BURST_LOG_S - self._clock()
        if wait <= 0:
            self.flush()
        elif not self._pending:
            self._pending = True
            self._later(wait, self.flush)

    def flush(self) -> None:
        self._pending = False
        if not self._unlogged:
            return
        self._logged_at = self._clock()
        what = ", ".join(f"{n} {WHY.get(r, r)}" for r, n in self._unlogged.items())
        self._unlogged = {}
        log.warning(
            "%s: refused connections (%s; cap %d; %d refused in all, "
            "summed into one line every %.0f s)",
            self.name,
            what,
            self.rules.max_connections,
            self.total,
            BURST_LOG_S,
        )

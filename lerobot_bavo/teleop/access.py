"""Who may use a `bavo-teleop` server: the Host and Origin checks and the per-run token.

Why: the server drives the robot and discards or saves episodes on request. Without checks, any
web page the operator's browser has open could open ws://127.0.0.1:8765/ws (browsers let pages
open websockets to any address; the server is the only one who can say no), and a site whose DNS
name is re-pointed at 127.0.0.1 ("DNS rebinding") could even read the page. So every request
must:

- name this server in `Host` (its bound address and port; for a loopback bind also `localhost`,
  `127.0.0.1` and `[::1]`; for a wildcard bind such as 0.0.0.0 any IP address or this machine's
  name). A rebinding page sends its own domain name, and is refused;
- if it carries `Origin` (browsers always send it on websocket upgrades), come from this server's
  own http origin, as named in `Host` (the loopback names count as one). A page elsewhere is
  refused. A request without `Origin` is not from a page on another site (browsers send one);
- except for the page's static script, carry the run's random token (`?token=...`, printed in
  the URL at start; the page passes it on to the websocket), compared in constant time. The token stops what
  the header checks cannot: another local user or program that knows the port.

`AccessPolicy.refusal` is pure (headers in, reason out) so each rule is tested on its own; the
server turns a reason into HTTP 403.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
from dataclasses import dataclass
from urllib.parse import urlsplit

LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
WILDCARD_ADDRESSES = frozenset({"", "0.0.0.0", "::"})


def new_token() -> str:
    """A fresh random token for one server run (URL-safe, 192 bits)."""
    return secrets.token_urlsafe(24)


def split_host(value: str) -> tuple[str, int | None]:
    """"name:port" / "[v6]:port" / "name" -> (lower-case name without brackets, port or None).

    Raises ValueError for text that is not a host (port not a number, unbalanced brackets)."""
    value = value.strip().lower()
    if value.startswith("["):
        end = value.find("]")
        if end < 0:
            raise ValueError(f"unbalanced '[' in {value!r}")
        name, rest = value[1:end], value[end + 1:]
        if rest and not rest.startswith(":"):
            raise ValueError(f"text after ']' in {value!r}")
        port = rest[1:] if rest else None
    elif value.count(":") == 1:
        name, port = value.split(":")
    else:
        name, port = value, None
    if not name:
        raise ValueError("empty host name")
    if port is None:
        return name, None
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"bad port {port!r}")
    return name, int(port)


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def is_loopback(name: str) -> bool:
    return name in LOOPBACK_NAMES or (_is_ip(name) and ipaddress.ip_address(name).is_loopback)


def url_host(name: str) -> str:
    """A host name as it goes into a URL (IPv6 addresses in brackets)."""
    return f"[{name}]" if ":" in name else name


@dataclass(frozen=True)
class AccessPolicy:
    """The names a request may use for this server, its port, and the run's token.

    Build it with `for_bound(host, port)` once the server is listening (the port may have been 0).
    """

    names: frozenset[str]
    port: int
    token: str
    any_ip: bool = False  # a wildcard bind: any IP literal names this server (rebinding needs a domain name)

    @classmethod
    def for_bound(cls, host: str, port: int, token: str) -> AccessPolicy:
        host = host.strip("[]").lower()
        if host in WILDCARD_ADDRESSES:
            names = {"localhost", socket.gethostname().lower(), socket.getfqdn().lower()}
            return cls(frozenset(names), port, token, any_ip=True)
        if is_loopback(host):
            return cls(LOOPBACK_NAMES | {host}, port, token)
        return cls(frozenset({host}), port, token)

    def url(self, host: str) -> str:
        """The page's address, with the token (what the operator opens)."""
        name = "127.0.0.1" if host.strip("[]") in WILDCARD_ADDRESSES else host.strip("[]")
        return f"http://{url_host(name)}:{self.port}/?token={self.token}"

    def _names_this_server(self, name: str, port: int | None) -> bool:
        return (port or 80) == self.port and (name in self.names or (self.any_ip and _is_ip(name)))

    def refusal(
        self, host: str | None, origin: str | None, token: str | None, need_token: bool
    ) -> str | None:
        """Why the request must be refused, or None when it may go on.

        Args:
            host, origin: the `Host` and `Origin` headers (None when absent).
            token: the request's `token` query parameter (None when absent).
            need_token: whether this route needs the token (all but the page's static script).
        """
        if not host:
            return "the request has no Host header"
        try:
            h_name, h_port = split_host(host)
        except ValueError as e:
            return f"the Host header {host[:80]!r} is not a host ({e})"
        if not self._names_this_server(h_name, h_port):
            return (f"the Host header {host[:80]!r} does not name this server (port {self.port}); "
                    "open the address bavo-teleop printed")
        if origin is not None:
            reason = self._origin_refusal(origin, h_name, h_port)
            if reason:
                return reason
        if need_token:
            if not token:
                return "no token: open the address bavo-teleop printed (it ends in ?token=...)"
            if not hmac.compare_digest(token.encode("utf-8", "surrogatepass"), self.token.encode()):
                return "wrong token: open the address bavo-teleop printed (a new token is made at each start)"
        return None

    def _origin_refusal(self, origin: str, h_name: str, h_port: int | None) -> str | None:
        refused = f"Origin {origin[:80]!r} is not this server's page (a request from another site)"
        try:
            parts = urlsplit(origin.strip())
            if parts.scheme != "http" or not parts.netloc or parts.path or parts.query or "@" in parts.netloc:
                return refused
            o_name, o_port = split_host(parts.netloc)
        except ValueError:
            return refused
        same = (o_name, o_port or 80) == (h_name, h_port or 80) or (
            is_loopback(o_name) and is_loopback(h_name)
        )
        return None if same and self._names_this_server(o_name, o_port) else refused

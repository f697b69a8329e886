"""Who may reach a server the SDK runs for browsers and apps (the Foxglove server's
front, the web dashboard): loopback, origins and tokens, checked one way for both.

A server beyond loopback needs a token (`check_token`: long enough not to be
guessed over the network, printable ASCII, compared in constant time by the caller); a
WebSocket handshake's ``Origin`` is compared by `origin_key` (RFC 6455 §10.2: a
page in the operator's browser must not reach the robot unless it is let in).
"""

from __future__ import annotations

import ipaddress
import secrets
from collections.abc import Iterable
from urllib.parse import parse_qs, urlsplit

__all__ = [
    "MIN_TOKEN_LENGTH",
    "check_allowed_origin",
    "check_token",
    "given_tokens",
    "is_loopback",
    "made_token",
    "origin_key",
]

#: The shortest token taken (a shorter one can be guessed over the network).
MIN_TOKEN_LENGTH = 16


def is_loopback(host: str) -> bool:
    """Whether ``host`` names this computer only (``localhost``, 127.0.0.0/8, ``::1``)."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: it may resolve to anything


def made_token(host: str, token: str | None, *, none: bool = False) -> tuple[str | None, bool]:
    """The token a server on ``host`` requires, and whether it was made now: the one
    given; else, beyond loopback and unless ``none`` (serve without one), a new one,
    which the caller shows once (the dashboard and ``chassis-sdk serve`` alike); else
    none."""
    if token is not None or none or is_loopback(host):
        return token, False
    return secrets.token_urlsafe(24), True


def origin_key(origin: str) -> str:
    """An origin as compared: lowercase, no trailing slash (browsers send none, but a
    user may type one)."""
    key = origin.strip().lower()
    return key if key == "file://" else key.rstrip("/")


def check_allowed_origin(origin: object) -> str:
    """``origin`` as compared (`origin_key`), if it may be let in.

    Raises:
        ValueError: Not ``scheme://host[:port]``, or ``null`` or ``*`` (any page).
    """
    if not isinstance(origin, str) or not origin.strip():
        raise ValueError(f"an allowed origin must be a non-empty string, got {origin!r}")
    key = origin_key(origin)
    if key == "null":
        # Sandboxed iframes and data: URLs of any site send "null": allowing it would
        # allow every page on the web.
        raise ValueError("the origin 'null' cannot be allowed: any page can send it")
    if key == "*":
        raise ValueError("'*' is not an origin; to allow any page, there is no option")
    parts = urlsplit(key)
    # Any scheme: a desktop app may send its own (app://..., as Electron apps can); the
    # refusal's log line shows what a refused app sent.
    if not parts.scheme or not parts.netloc or parts.path or parts.query or parts.fragment:
        raise ValueError(
            f"an allowed origin is scheme://host[:port] (as a browser sends it), got {origin!r}"
        )
    return key


def check_token(token: object) -> str:
    """``token``, if it is one a server may require.

    Raises:
        TypeError: Not a string.
        ValueError: Shorter than `MIN_TOKEN_LENGTH`, or not printable ASCII
            without spaces.
    """
    if not isinstance(token, str):
        raise TypeError("token must be a string")
    if len(token) < MIN_TOKEN_LENGTH:
        raise ValueError(f"token must be at least {MIN_TOKEN_LENGTH} characters")
    if not all(33 <= ord(c) <= 126 for c in token):
        raise ValueError("token must be printable ASCII without spaces")
    return token


def given_tokens(path: str, authorization: Iterable[str]) -> list[str]:
    """The tokens a request carries: ``?token=`` in ``path`` (a request target) and
    each ``Authorization: Bearer`` value."""
    given = parse_qs(urlsplit(path).query, keep_blank_values=True).get("token", [])
    for value in authorization:
        scheme, _, credentials = value.partition(" ")
        if scheme.lower() == "bearer":
            given.append(credentials.strip())
    return given

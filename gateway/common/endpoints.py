"""ZeroMQ endpoints: the defaults, what counts as one, and which ones other hosts can
reach; and the metrics endpoint's HOST:PORT."""

from __future__ import annotations

import ipaddress

DEFAULT_PUBLISH = "tcp://127.0.0.1:5555"
DEFAULT_CONTROL = "tcp://127.0.0.1:5556"
DEFAULT_METRICS = "127.0.0.1:9105"
DEFAULT_LIVE = "127.0.0.1:8765"
"""The live view's (Foxglove's own default port)."""
WILDCARD_HOSTS = ("*", "0.0.0.0", "::", "[::]", "[*]")


def check_endpoint(value: str) -> str:
    """A ZeroMQ endpoint the gateway can bind or a client connect; ValueError if not."""
    scheme, sep, rest = value.partition("://")
    host, colon, port = rest.rpartition(":")
    if (not sep or scheme not in ("tcp", "ipc", "inproc") or not rest
            or (scheme == "tcp" and not (colon and host and (port.isdigit() or port == "*")))):
        raise ValueError(f"must be a ZeroMQ endpoint such as tcp://127.0.0.1:5556 or "
                         f"ipc:///run/gx2-gateway/control, not {value!r}")
    return value


def is_loopback(endpoint: str) -> bool:
    """ipc://, inproc://, or tcp:// on a loopback address: unreachable from elsewhere."""
    scheme, _, rest = endpoint.partition("://")
    if scheme != "tcp":
        return True
    host = rest.rpartition(":")[0].strip("[]")
    if host in ("localhost", "lo"):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # *, a host name or an interface name: possibly reachable


def tcp_host(address: str) -> str | None:
    scheme, _, rest = address.partition("://")
    return rest.rpartition(":")[0] if scheme == "tcp" else None


def connectable(address: str, near: str) -> str:
    """A bind address (``tcp://*:5555``) turned into one to connect to: the host of
    ``near`` (the control endpoint) if that is concrete, else the loopback."""
    host = tcp_host(address)
    if host not in WILDCARD_HOSTS:
        return address
    other = tcp_host(near)
    concrete = other if other and other not in WILDCARD_HOSTS else "127.0.0.1"
    return f"tcp://{concrete}:{address.rpartition(':')[2]}"


def host_port(value: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port): ``[::1]:9105`` for IPv6, and a bare ``:9105`` or
    ``9105`` on the loopback. ValueError if it is not such an address."""
    host, colon, port = value.rpartition(":")
    if not colon:
        host, port = "", value
    bracketed = host.startswith("[") and host.endswith("]")
    if bracketed:
        host = host[1:-1]
        if ":" not in host:  # ([] and [127.0.0.1] are no IPv6 addresses)
            raise ValueError(f"only an IPv6 address goes in brackets, not {value!r}")
    if not (port.isascii() and port.isdecimal() and 1 <= int(port) <= 65535) or any(
            c.isspace() or c in "/[]" for c in host):
        raise ValueError(f"must be HOST:PORT with a port 1..65535, such as "
                         f"{DEFAULT_METRICS}, not {value!r}")
    if ":" in host and not bracketed:
        raise ValueError(f"an IPv6 address goes in brackets: [{host}]:{port}")
    return host or "127.0.0.1", int(port)


def check_host_port(value: str) -> str:
    host_port(value)
    return value

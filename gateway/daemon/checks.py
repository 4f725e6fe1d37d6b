"""What ``gx2-gateway --check`` tells beyond the file itself: the state of this host that
a start would meet. What no start could get past is exit 2 (:func:`unwritable`, a
recording directory this user cannot write; :func:`live_refusal`; :func:`lsl_refusal`,
``lsl:`` without a liblsl that loads); what
would not stop a start, or is of this moment and often gone by the time the gateway
starts, is a warning, one line each (:func:`warnings`), and the check still passes:

- a device path that does not exist: the adapter may be plugged in later, and the
  gateway opens it when it is (it retries every second);
- an endpoint another process holds: most often the running gateway this file is about
  to replace (``--check`` before ``systemctl restart``), which frees it as it stops.
  A start while it is held fails (exit 1, "cannot bind");
- an MQTT user and password that would go to another host unencrypted (``mqtt://``):
  the start says it too, once.

Nothing is left open and nothing is changed: an endpoint is tried by binding it and
letting it go at once; an ``ipc://`` one by connecting to it, since ZeroMQ's bind would
take its path from the process that holds it.
"""

from __future__ import annotations

import errno
import os
import pwd
import socket
import stat
import tempfile
from pathlib import Path

import zmq

from gateway.common.endpoints import host_port

from .config import GatewayConfig

HELD = "is held by another process (a gateway running?): a gateway cannot start on it " \
       "until that process lets it go"
IPC_PROBE_S = 0.5
"""Seconds a connection to an ipc:// endpoint may take to tell whether it is served."""


def warnings(config: GatewayConfig) -> list[str]:
    """One line each, ``key: what``, for what a start would meet but not fail on."""
    cleartext = config.mqtt.cleartext() if config.mqtt is not None else None
    return [*missing_devices(config), *held_endpoints(config),
            *([cleartext] if cleartext else [])]


def missing_devices(config: GatewayConfig) -> list[str]:
    return [f"{where}.port: {station.port} does not exist (yet?): the gateway starts all "
            "the same and opens it once it is plugged in"
            for where, station in config.placed_stations()
            if "://" not in station.port and not os.path.lexists(station.port)]


def held_endpoints(config: GatewayConfig) -> list[str]:
    found = [(key, endpoint, _zmq_refusal(endpoint)) for key, endpoint in (
        ("publish.endpoint", config.publish.endpoint),
        ("control.endpoint", config.control.endpoint))]
    for key, section in (("metrics.endpoint", config.metrics), ("live.endpoint", config.live)):
        if section is not None:
            found.append((key, section.endpoint, _tcp_refusal(section.endpoint)))
    return [f"{key}: {endpoint} {why}" for key, endpoint, why in found if why]


def _why(error: OSError) -> str:
    if error.errno == errno.EADDRINUSE:
        return HELD
    return (f"cannot be bound now ({error.strerror or error}): a gateway cannot start on "
            "it as it is")


def _zmq_refusal(endpoint: str) -> str | None:
    """Why the gateway could not bind a ZeroMQ endpoint now (None: it could)."""
    scheme, _, rest = endpoint.partition("://")
    if scheme == "ipc":
        return _ipc_refusal(rest)
    if scheme != "tcp" or rest.endswith(":*"):
        return None  # (inproc:// is the process's own; port * is any free one)
    context = zmq.Context()
    probe = context.socket(zmq.PUB)
    probe.setsockopt(zmq.LINGER, 0)
    try:
        probe.bind(endpoint)
    except zmq.ZMQError as error:
        return _why(OSError(error.errno, error.strerror))
    finally:
        probe.close()
        context.term()
    return None


def _ipc_refusal(path: str) -> str | None:
    """A served ipc:// path answers a connection; a stale one (a gateway that was
    killed) refuses it, and the gateway's bind replaces it."""
    address = "\0" + path[1:] if path.startswith("@") else path  # (Linux's abstract names)
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        probe.settimeout(IPC_PROBE_S)
        try:
            probe.connect(address)
        except OSError:
            return None  # nothing there, a stale file, or not ours to judge
    return HELD


def _tcp_refusal(endpoint: str) -> str | None:
    """Why a server could not listen on ``HOST:PORT`` (metrics, live) now."""
    host, port = host_port(endpoint)
    try:
        family, kind, proto, _, address = socket.getaddrinfo(
            host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)[0]
    except socket.gaierror as error:
        return f"cannot be bound now ({error.strerror}): a gateway cannot start on it as it is"
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(address)
        except OSError as error:
            return _why(error)
    return None


def unwritable(directory: str) -> str | None:
    """Why the recorder could not write files in ``directory`` as this user, or None.

    Nothing is created: a missing directory is judged by its nearest existing ancestor
    (the recorder makes the rest). Writing is tried rather than asked: ``os.access``
    answers for the real, not the effective, user and knows nothing of AppArmor, quotas
    or a full inode table. The probe is an unnamed temporary file (O_TMPFILE, or one
    unlinked at once where the file system has no O_TMPFILE): nothing is left behind."""
    target = Path(directory).absolute()
    nearest = target
    while True:
        try:
            mode = nearest.stat().st_mode
            break
        except (FileNotFoundError, NotADirectoryError):
            nearest = nearest.parent
        except OSError as error:
            # a directory on the way that this user may not search
            return f"cannot be reached by user {_user()} ({error.strerror})"
    missing = "" if nearest == target else f"cannot be created: {nearest} "
    if not stat.S_ISDIR(mode):
        return f"{missing}is not a directory"
    try:
        with tempfile.TemporaryFile(dir=nearest):
            pass
    except OSError as error:
        return f"{missing}is not writable by user {_user()} ({error.strerror})"
    return None


def _user() -> str:
    uid = os.geteuid()
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)


def live_refusal(config: GatewayConfig) -> str | None:
    """``live.tls_cert``/``live.tls_key: why`` if the live view's server would refuse
    them at start (None if it would take them, or there is no TLS)."""
    if config.live is None or config.live.tls_cert is None:
        return None
    from .outputs.live import tls_refusal  # (foxglove-sdk: only when it is configured)
    why = tls_refusal(config.live)
    if why is None:
        return None
    key = "tls_key" if "key" in why else "tls_cert"
    return f"live.{key}: {getattr(config.live, key)}: the live view's server refuses it: {why}"


def lsl_refusal(config: GatewayConfig) -> str | None:
    """``lsl: how to install liblsl`` if pylsl or its liblsl cannot be loaded here (None
    without ``lsl:``: pylsl is then never imported)."""
    if config.lsl is None:
        return None
    from .outputs.lsl import refusal  # (pylsl: only when it is configured)
    return refusal()

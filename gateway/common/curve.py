"""CURVE for the control and publish sockets: key files, and who may connect.

Keys are ZeroMQ's Z85 text (40 characters). A key pair lives in two files in the
format pyzmq and CZMQ share (``zmq.auth.load_certificate`` reads them):
``NAME.key`` with the public key (mode 0644, handed to whoever must know it) and
``NAME.key_secret`` with both keys (mode 0600, never leaves its host). The gateway
holds a server pair; each client (gx2ctl, a subscriber) holds its own, and the gateway
lets in only the client public keys its configuration lists (ZAP, ZeroMQ's
authentication hook). Light on purpose: gx2ctl imports it on every run.
"""

from __future__ import annotations

import logging
import os
import stat
import struct
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.utils import z85

log = logging.getLogger("gx2.curve")
KEY_LENGTH = 40
PUBLIC_SUFFIX, SECRET_SUFFIX = ".key", ".key_secret"


class CurveError(ValueError):
    """A key cannot be used (one line naming the file or the key)."""


@dataclass(frozen=True)
class KeyPair:
    public: bytes
    secret: bytes


@dataclass(frozen=True)
class ClientKeys:
    """What a client connects with: its own pair and the gateway's public key."""

    client: KeyPair
    server_public: bytes


def is_z85_key(text: str) -> bool:
    if len(text) != KEY_LENGTH:
        return False
    try:
        z85.decode(text.encode("ascii"))
    except (ValueError, UnicodeEncodeError, KeyError, struct.error):
        return False
    return True


def _read(path: Path) -> tuple[bytes, bytes | None]:
    try:
        public, secret = zmq.auth.load_certificate(path)
    except OSError as error:
        raise CurveError(f"{path}: {error.strerror or error}") from None
    except (ValueError, KeyError, UnicodeDecodeError):
        raise CurveError(f"{path}: not a ZeroMQ key file (make one with gx2ctl "
                         "keygen)") from None
    if public is None or not is_z85_key(public.decode("ascii", "replace")):
        raise CurveError(f"{path}: no valid public-key in it")
    if secret is not None and not is_z85_key(secret.decode("ascii", "replace")):
        raise CurveError(f"{path}: its secret-key is not a valid key")
    return public, secret


def load_key_pair(path: str | Path) -> KeyPair:
    """Both keys from a ``.key_secret`` file, which others must not be able to read."""
    path = Path(path)
    public, secret = _read(path)
    if secret is None:
        raise CurveError(f"{path}: holds no secret-key (that is a public {PUBLIC_SUFFIX} "
                         f"file; the pair is in {SECRET_SUFFIX})")
    if path.stat().st_mode & stat.S_IROTH:
        raise CurveError(f"{path}: a secret key readable by every user is not secret "
                         f"(chmod o-r {path})")
    return KeyPair(public, secret)


def public_key(text: str) -> bytes:
    """A public key given as its 40 Z85 characters or as a key file holding it."""
    if is_z85_key(text):
        return text.encode("ascii")
    path = Path(text)
    if not path.exists():
        raise CurveError(f"{text!r} is neither a 40-character Z85 key nor a key file")
    return _read(path)[0]


def load_client_keys(client_secret: str | Path, server: str) -> ClientKeys:
    """A client's keys: its ``.key_secret`` file, and the gateway's public key (Z85
    text, its ``.key`` file, or its ``.key_secret`` file); CurveError if unusable."""
    pair = load_key_pair(client_secret)
    server_public = (load_key_pair(server).public if server.endswith(SECRET_SUFFIX)
                     else public_key(server))
    return ClientKeys(pair, server_public)


def public_sibling(secret_path: str | Path) -> Path:
    """``server.key`` for ``server.key_secret``: where the public half is kept."""
    path = Path(secret_path)
    if path.name.endswith(SECRET_SUFFIX):
        return path.with_name(path.name[:-len(SECRET_SUFFIX)] + PUBLIC_SUFFIX)
    return path.with_name(path.name + PUBLIC_SUFFIX)


def generate(prefix: str | Path) -> tuple[Path, Path]:
    """Write a new pair as ``PREFIX.key`` (0644) and ``PREFIX.key_secret`` (0600);
    neither file may exist already (an old key is never overwritten)."""
    prefix = Path(prefix)
    public_path = prefix.with_name(prefix.name + PUBLIC_SUFFIX)
    secret_path = prefix.with_name(prefix.name + SECRET_SUFFIX)
    for path in (public_path, secret_path):
        if path.exists():
            raise CurveError(f"{path} already exists; remove it or choose another name")
    public, secret = zmq.curve_keypair()
    _write(secret_path, 0o600, public, secret)
    _write(public_path, 0o644, public, None)
    return public_path, secret_path


def _write(path: Path, mode: int, public: bytes, secret: bytes | None) -> None:
    lines = ["#   ZeroMQ CURVE key, written by gx2ctl keygen",
             "#   " + ("SECRET: keep this file private" if secret else
                       "public: give it to whoever must know this key"),
             "metadata", "curve", f'    public-key = "{public.decode()}"']
    if secret is not None:
        lines.append(f'    secret-key = "{secret.decode()}"')
    try:  # created with its mode, never readable by others even for an instant
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, mode)
    except OSError as error:
        raise CurveError(f"{path}: {error.strerror or error}") from None
    with os.fdopen(fd, "w", encoding="ascii") as file:
        file.write("\n".join(lines) + "\n")
    os.chmod(path, mode)  # whatever the umask


# --- sockets ------------------------------------------------------------------------------

def serve(socket: zmq.Socket, server: KeyPair) -> None:
    """Make ``socket`` (before it binds) a CURVE server with this pair."""
    socket.curve_secretkey = server.secret
    socket.curve_publickey = server.public
    socket.curve_server = True


def connect_as(socket: zmq.Socket, keys: ClientKeys) -> None:
    """Make ``socket`` (before it connects) a CURVE client of that server."""
    socket.curve_secretkey = keys.client.secret
    socket.curve_publickey = keys.client.public
    socket.curve_serverkey = keys.server_public


class AllowList:
    """ZAP's credentials callback: only the configured client keys get in."""

    def __init__(self, keys: frozenset[bytes]) -> None:
        self.keys = keys
        self.denied = 0
        self._named: set[bytes] = set()

    def callback(self, domain: str, key: bytes) -> bool:
        if key in self.keys:
            return True
        self.denied += 1
        if len(self._named) < 256 and key not in self._named:  # (a refused client
            self._named.add(key)                                # retries every 0.1 s)
            log.warning("refused a CURVE client whose key is not allowed: %s",
                        key.decode())
        return False

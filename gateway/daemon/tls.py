"""The live view's certificate and key (``live.tls_cert``, ``live.tls_key``), and the
MQTT output's (``mqtt.tls_ca``, ``tls_cert``, ``tls_key``), checked as the
configuration is read: a file foxglove-sdk cannot use fails ``--check`` (exit 2,
naming the key), not the start that follows it.

Python's ``ssl`` parses them (OpenSSL): it accepts what the SDK's rustls takes (PEM
certificates; PKCS#8, PKCS#1 and SEC1 keys) and refuses, with a reason, what it refuses
(no PEM item of the kind, a key of another certificate, an encrypted key).
"""

from __future__ import annotations

import os
import ssl


class _Encrypted(Exception):
    """OpenSSL asked for a passphrase: the key is encrypted."""


def _no_passphrase() -> str:
    raise _Encrypted


def _readable(path: str) -> None:
    # a regular file only: OpenSSL raises a bare OSError for a directory, and blocks
    # reading a FIFO until something writes to it
    if not os.path.isfile(path):
        raise ValueError(f"{path}: not a file" if os.path.exists(path)
                         else f"{path}: no such file")
    if not os.access(path, os.R_OK):
        raise ValueError(f"cannot read {path}")


def check_cert(path: str | None) -> str | None:
    """``path`` if it holds a PEM certificate; ValueError (one line) if not."""
    if path is not None:
        _readable(path)
        try:
            ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_verify_locations(cafile=path)
        except OSError as error:
            if not isinstance(error, ssl.SSLError):  # (read between the check and here)
                raise ValueError(f"{path}: {error.strerror or error}") from None
            why = ("no PEM certificate in it" if error.reason == "NO_CERTIFICATE_OR_CRL_FOUND"
                   else f"not a PEM certificate ({error.reason or error})")
            raise ValueError(f"{path}: {why}") from None
    return path


def check_key(path: str | None, cert: str | None) -> str | None:
    """``path`` if it holds the PEM private key of ``cert``'s certificate (not checked
    against a ``cert`` that is None: that one has its own error); ValueError if not."""
    if path is None:
        return path
    _readable(path)
    if cert is None:
        return path
    try:
        ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER).load_cert_chain(cert, path,
                                                                password=_no_passphrase)
    except _Encrypted:
        raise ValueError(f"{path}: is encrypted: give a key without a passphrase (the "
                         "gateway starts unattended)") from None
    except OSError as error:
        if not isinstance(error, ssl.SSLError):
            raise ValueError(f"{path}: {error.strerror or error}") from None
        why = (f"is the key of another certificate than tls_cert's ({cert})"
               if error.reason == "KEY_VALUES_MISMATCH"
               else "no PEM private key in it" if error.library == "SSL"
               else f"not a PEM private key ({error.reason or error})")
        raise ValueError(f"{path}: {why}") from None
    return path

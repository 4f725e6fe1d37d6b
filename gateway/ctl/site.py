"""Where the gateways gx2ctl talks to are: ``--config`` or ``--control`` (each may be
given more than once), a ``gateways:`` file in place of a configuration, CURVE keys
from the options, the environment or the configuration. Every mistake here is a usage
error (exit 2) in one line.

A gateways file lists a site's gateways, each by its configuration or its control
endpoint, and names them (a configuration path is read relative to the file)::

    gateways:
      - name: hall-a
        config: hall-a.yaml
      - name: hall-b
        control: tcp://10.0.0.12:5556
        server_key: hall-b.key

``server_key:`` (a gateway's public key or its file, read relative to the gateways
file) is that gateway's own; one given with ``--server-key`` or the environment
applies to the others. Keys apply only to gateways that use CURVE: a gateway whose
configuration has no ``curve:`` is connected to in plain.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from gateway.common import curve
from gateway.common.endpoints import DEFAULT_CONTROL, check_endpoint
from gateway.common.protocol import Exit

from .client import CtlError
from .where import Endpoints, Gateway

CLIENT_KEY_ENV, SERVER_KEY_ENV = "GX2_CLIENT_KEY", "GX2_SERVER_KEY"
LIST_KEY = "gateways"
ENTRY_KEYS = frozenset(("name", "config", "control", "server_key"))
Entry = tuple[str | None, str | None, str | None, str | None]
"""A gateway as a gateways file lists it: (name, config, control, server_key)."""


def gateways(args: argparse.Namespace) -> list[Gateway]:
    """Every gateway the command line names, in its order (the default control
    endpoint when it names none); a gateways file stands for the gateways it lists."""
    configs, controls = args.config or [], args.control or []
    if not configs and not controls:
        return [Gateway(DEFAULT_CONTROL, endpoints(args, None, None))]
    entries: list[Entry] = []
    for path in configs:
        listed = site_entries(path)
        entries += listed if listed is not None else [(None, path, None, None)]
    entries += [(None, None, control, None) for control in controls]
    named = []
    for name, config, control, server_key in entries:
        try:
            where = endpoints(args, config, control, server_key)
        except CtlError as error:
            if len(entries) == 1:
                raise
            raise CtlError(f"{name or config or control}: {error}", error.status) from None
        named.append(Gateway(name or "", where, config))
    return _distinct(_named(named))


def site_entries(path: str) -> list[Entry] | None:
    """The (name, config, control, server_key) entries of a gateways file, or None if ``path`` is
    not one (a gateway's configuration: its own loader judges it)."""
    import yaml  # loaded only when a file is named, as the configuration's loader is
    try:
        document = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        return None  # the configuration loader says what is wrong, in its words
    if not isinstance(document, Mapping) or LIST_KEY not in document:
        return None
    if set(document) != {LIST_KEY}:
        extra = sorted(str(key) for key in set(document) - {LIST_KEY})
        raise CtlError(f"{path}: a gateways file has only '{LIST_KEY}:', not "
                       f"{', '.join(extra)}", Exit.USAGE)
    listed = document[LIST_KEY]
    if not isinstance(listed, list) or not listed:
        raise CtlError(f"{path}: '{LIST_KEY}' must be a list of gateways, each with "
                       "config: or control:", Exit.USAGE)
    return [_entry(path, number, entry) for number, entry in enumerate(listed, 1)]


def _entry(path: str, number: int, entry: Any) -> Entry:
    where = f"{path}: {LIST_KEY}[{number}]"
    if not isinstance(entry, Mapping):
        raise CtlError(f"{where}: a map with config: or control: (and name:), not "
                       f"{entry!r}", Exit.USAGE)
    unknown = sorted(str(key) for key in set(entry) - ENTRY_KEYS)
    if unknown:
        raise CtlError(f"{where}: unknown key {unknown[0]} (it takes name, config, "
                       "control, server_key)", Exit.USAGE)
    values = {}
    for key in ENTRY_KEYS & set(entry):
        if not isinstance(entry[key], str) or not entry[key].strip():
            raise CtlError(f"{where}.{key}: a string, not {entry[key]!r}", Exit.USAGE)
        values[key] = entry[key].strip()
    if ("config" in values) == ("control" in values):
        raise CtlError(f"{where}: give config: or control:, one of them", Exit.USAGE)
    config, control = values.get("config"), values.get("control")
    if config is not None:
        config = str(Path(path).parent / Path(config).expanduser())
    if control is not None:
        try:
            control = check_endpoint(control)
        except ValueError as error:
            raise CtlError(f"{where}.control: {error}", Exit.USAGE) from None
    server_key = values.get("server_key")
    if server_key is not None and not curve.is_z85_key(server_key):
        server_key = str(Path(path).parent / Path(server_key).expanduser())
    return values.get("name"), config, control, server_key


def _named(found: list[Gateway]) -> list[Gateway]:
    """Each gateway without a name of its own named by its configuration's file name
    (``hall-a`` for hall-a.yaml), or its whole path where two would share one; or by
    its control endpoint."""
    stems = [Path(g.config).stem if g.config else None for g in found]
    named = []
    for gateway, stem in zip(found, stems, strict=True):
        name = gateway.name or (stem if stem and stems.count(stem) == 1
                                else gateway.config or gateway.where.control)
        named.append(Gateway(name, gateway.where, gateway.config))
    return named


def _distinct(found: list[Gateway]) -> list[Gateway]:
    seen_names: set[str] = set()
    seen_controls: dict[str, str] = {}
    for number, gateway in enumerate(found, 1):
        if (other := seen_controls.get(gateway.where.control)) is not None:
            raise CtlError(f"{other} and gateway {number} ({gateway.name}) are the same "
                           f"gateway (control {gateway.where.control})", Exit.USAGE)
        seen_controls[gateway.where.control] = gateway.name
        if gateway.name in seen_names:
            raise CtlError(f"two gateways are named {gateway.name}: name them apart in a "
                           "gateways file", Exit.USAGE)
        seen_names.add(gateway.name)
    return found


def endpoints(args: argparse.Namespace, config_path: str | None,
              control: str | None, own_key: str | None = None) -> Endpoints:
    """One gateway's endpoints: from its configuration (loaded here: its errors exit 2),
    its control endpoint, or the default; CURVE keys from its gateways file entry
    (``own_key``), the options, the environment, or its configuration (which alone
    says whether it uses CURVE at all)."""
    client_key = args.client_key or os.environ.get(CLIENT_KEY_ENV)
    server_key = own_key or args.server_key or os.environ.get(SERVER_KEY_ENV)
    if config_path is None:
        keys = client_keys(client_key, server_key, None)
        return Endpoints(control or DEFAULT_CONTROL, None, keys)
    # the gateway's own validator (pydantic): loaded only when a config is used
    from gateway.daemon.config import ConfigError, load_config
    try:
        config = load_config(config_path)
    except ConfigError as error:
        raise CtlError(str(error), Exit.USAGE) from None
    secured = config.curve is not None
    if secured and server_key is None:  # (none given: the one its configuration names)
        sibling = curve.public_sibling(config.curve.server_key)
        server_key = str(sibling) if sibling.exists() else config.curve.server_key
    keys = client_keys(client_key, server_key, config_path) if secured else None
    return Endpoints(config.control.endpoint, config.publish.endpoint, keys,
                     secured and config.curve.publish, config.publish.heartbeat_s,
                     tuple(n.address for n in config.all_nodes))


def client_keys(client_key: str | None, server_key: str | None,
                secured_by: str | None) -> curve.ClientKeys | None:
    """The CURVE keys to connect with, or None for a plain connection."""
    if client_key is None and server_key is None and secured_by is None:
        return None
    if client_key is None:
        why = f"{secured_by} configures curve" if secured_by else "--server-key is given"
        raise CtlError(f"{why}: give this client's key pair with --client-key FILE or "
                       f"${CLIENT_KEY_ENV} (make one with gx2ctl keygen)", Exit.USAGE)
    if server_key is None:
        raise CtlError(f"--client-key is given: give the gateway's public key with "
                       f"--server-key KEY or ${SERVER_KEY_ENV}", Exit.USAGE)
    try:
        return curve.load_client_keys(client_key, server_key)
    except curve.CurveError as error:
        raise CtlError(str(error), Exit.USAGE) from None

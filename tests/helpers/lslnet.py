"""Running what starts an LSL outlet or inlet where nothing it sends can leave this
machine: a private network namespace with only the loopback up (``unshare --net``, as
root), and an LSL configuration (``LSLAPICFG``) that resolves on this machine alone,
under a session id of its own, so that no stream of another run is ever found.

LSL finds streams by multicast; nothing here may ever reach the host's network, so
every test of the LSL output runs its gateway, simulator and inlet in here, and none
in the pytest process itself.
"""

from __future__ import annotations

import functools
import json
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

REPOSITORY = Path(__file__).resolve().parents[2]
LSL_CONFIG = """\
[ports]
IPv6 = disable
[multicast]
ResolveScope = machine
[lab]
SessionID = {session}
KnownPeers = {{127.0.0.1}}
"""
"""liblsl's configuration file keys (its lsl_api.cfg): resolution on this machine
alone (the machine scope's multicast group, on the loopback), streams of this session
only, the loopback as the one known peer."""


@functools.cache
def namespace_refusal() -> str | None:
    """Why no private network namespace can be made here (None: it can)."""
    if shutil.which("unshare") is None or shutil.which("ip") is None:
        return "unshare or ip is not installed"
    if os.geteuid() != 0:
        return "making a network namespace takes root"
    done = subprocess.run(["unshare", "--net", "sh", "-c", "ip link set lo up"],
                          capture_output=True, text=True, timeout=10)
    if done.returncode != 0:
        return f"unshare --net failed: {done.stderr.strip()}"
    return None


def lsl_environment(directory: Path) -> dict[str, str]:
    """The environment of a process in the namespace: LSLAPICFG naming a configuration
    file of this run's own, with a unique session id."""
    config = directory / "lsl_api.cfg"
    config.write_text(LSL_CONFIG.format(session=f"gx2-test-{uuid.uuid4().hex}"))
    return {**os.environ, "LSLAPICFG": str(config)}


def in_namespace(argv: list[str]) -> list[str]:
    """``argv`` run in a new network namespace with the loopback up and nothing else."""
    return ["unshare", "--net", "sh", "-c", 'ip link set lo up && exec "$@"', "sh", *argv]


def run_probe(module: str, options: dict[str, Any], directory: Path,
              timeout: float = 90.0) -> dict[str, Any]:
    """``python -m module OPTIONS_JSON`` in a namespace of its own (run from the
    repository, working in ``directory``, given as the option ``directory``); the last
    line it prints, as JSON."""
    options = {**options, "directory": str(directory)}
    done = subprocess.run(in_namespace([sys.executable, "-m", module, json.dumps(options)]),
                          env=lsl_environment(directory), cwd=REPOSITORY, capture_output=True,
                          text=True, timeout=timeout)
    if done.returncode != 0:
        raise AssertionError(f"{module} exited {done.returncode}:\n{done.stdout}\n"
                             f"{done.stderr}")
    return json.loads(done.stdout.splitlines()[-1])  # type: ignore[no-any-return]

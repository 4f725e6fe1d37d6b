"""Several gateways named on gx2ctl's command line or in a gateways file: mistakes are
one line and exit 2, before anything is asked of a gateway; ``record`` refuses two
gateways that share a node address."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gateway.ctl.client import CtlError
from gateway.ctl.record import apart
from gateway.ctl.subscribing import Source
from gateway.ctl.where import Endpoints, Gateway
from tests.helpers.processes import gx2ctl


@pytest.mark.parametrize(("listed", "said"), [
    ("gateways: []\n", "'gateways' must be a list of gateways"),
    ("gateways:\n  - name: a\n", "gateways[1]: give config: or control:, one of them"),
    ("gateways:\n  - control: tcp://127.0.0.1:1\n    config: x.yaml\n",
     "gateways[1]: give config: or control:, one of them"),
    ("gateways:\n  - contrl: tcp://127.0.0.1:1\n", "gateways[1]: unknown key contrl"),
    ("gateways:\n  - control: nowhere\n", "gateways[1].control: "),
    ("gateways:\n  - control: tcp://127.0.0.1:1\n    name: a\n"
     "  - control: tcp://127.0.0.1:2\n    name: a\n", "two gateways are named a"),
    ("gateways:\n  - control: tcp://127.0.0.1:1\n  - control: tcp://127.0.0.1:1\n",
     "are the same gateway"),
    ("gateways: [{control: 'tcp://127.0.0.1:1'}]\nnodes: []\n",
     "a gateways file has only 'gateways:', not nodes"),
])
def test_a_broken_gateways_file_is_one_line_and_exit_2(tmp_path: Path, listed: str,
                                                       said: str) -> None:
    path = tmp_path / "site.yaml"
    path.write_text(listed)
    run = gx2ctl("--config", str(path), "--timeout", "0.2", "status")
    assert run.status == 2 and run.stdout == "", run
    assert run.stderr.startswith("gx2ctl: ") and run.stderr.count("\n") == 1, run.stderr
    assert said in run.stderr, run.stderr


def test_a_configuration_named_twice_is_one_gateway_twice(tmp_path: Path) -> None:
    config = Path(__file__).resolve().parents[2] / "config" / "demo.yaml"
    run = gx2ctl("--config", str(config), "--config", str(config), "status")
    assert run.status == 2 and "are the same gateway" in run.stderr, run


def _found(name: str, *nodes: int) -> tuple[Gateway, Source]:
    return (Gateway(name, Endpoints(f"ipc:///{name}", None)),
            Source(f"ipc:///{name}-pub", None, 3.0, nodes))


def test_record_refuses_a_node_address_two_gateways_have() -> None:
    found = [_found("hall-a", 76, 77), _found("hall-b", 77, 90)]
    with pytest.raises(CtlError, match="node 77 is in both hall-a and hall-b") as caught:
        apart([], found)
    assert caught.value.status == 2
    apart([76, 90], found)  # the nodes named differ: recorded together


def test_dead_gateways_are_asked_side_by_side_and_each_is_a_line(tmp_path: Path) -> None:
    """Two gateways that never answer cost one --timeout, not two; each is a line
    saying so; exit 3 (the worst); --json says which, with its error."""
    dead = [f"ipc://{tmp_path}/dead-{n}" for n in (1, 2)]
    timeout = 3.0  # (asked one after the other: 6 s and more; the rest, the program's
    # start and exit, which took 2.1 s beside the suite's other processes on two cores)
    run = gx2ctl("--control", dead[0], "--timeout", f"{timeout:g}", "status",
                 "--control", dead[1])
    assert run.status == 3, run
    assert run.seconds < 2 * timeout - 0.1, f"asked one after the other: {run.seconds:.1f} s"
    titles = [line for line in run.stdout.splitlines() if line.startswith("== ")]
    assert [t.split(": no answer")[0] for t in titles] == [f"== {d}" for d in dead] * 2
    assert run.stderr.startswith("gx2ctl: 2 of 2 gateways did not answer: ")
    shown = gx2ctl("--control", dead[0], "--control", dead[1], "--timeout", "0.5",
                   "--json", "status")
    assert shown.status == 3
    gateways = json.loads(shown.stdout)["gateways"]
    assert [(g["name"], g["control"]) for g in gateways] == [(d, d) for d in dead]
    assert all("no answer" in g["error"] for g in gateways)


def test_config_and_control_mix(tmp_path: Path) -> None:
    """A gateway named by its configuration and another by its control endpoint are
    two gateways (issue 43: the two options were refused together)."""
    config = tmp_path / "hall-a.yaml"
    config.write_text(f"base_station: {{port: 'sim://'}}\nnodes: []\n"
                      f"control: {{endpoint: 'ipc://{tmp_path}/a-control'}}\n"
                      f"publish: {{endpoint: 'ipc://{tmp_path}/a-publish'}}\n")
    dead = f"ipc://{tmp_path}/b-control"
    for order in (["--config", str(config), "--control", dead],
                  ["--control", dead, "status", "--config", str(config)]):
        run = gx2ctl(*order, "--timeout", "0.5", *(["status"] if order[-1] == dead else []))
        assert run.status == 3, run
        titles = [line.split(": no answer")[0] for line in run.stdout.splitlines()
                  if line.startswith("== ")]
        assert set(titles) == {"== hall-a", f"== {dead}"}, run

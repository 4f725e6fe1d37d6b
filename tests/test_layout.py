"""The Foxglove layout shipped beside the configurations (config/foxglove-layout.json):
its panels name what the demo configuration publishes (a 3D panel on the frame every
node's frame hangs from, with the demo's frames; plots of fields its records have; the
status), the demo streams an orientation so the 3D panel moves, and the wheel ships it."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path
from typing import Any

import yaml

from gateway.common.schemas import schema_for_topic
from gateway.daemon.outputs.frames import PARENT_FRAME, Frames, child_frame

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "config" / "foxglove-layout.json"
PATH = re.compile(r'^"(?P<topic>[^"]+)"\.(?P<field>\w+)\[(?P<index>\d)\]$')
"""A plot's message path: the quoted topic (no leading slash), a field, an element."""


def demo() -> dict[str, Any]:
    return yaml.safe_load((REPO / "config" / "demo.yaml").read_text())


def panels_in(tree: Any) -> set[str]:
    if isinstance(tree, str):
        return {tree}
    return panels_in(tree["first"]) | panels_in(tree["second"])


def test_every_panel_is_laid_out_and_each_is_one_the_layout_configures() -> None:
    layout = json.loads(LAYOUT.read_text())
    assert panels_in(layout["layout"]) == set(layout["configById"])
    kinds = sorted(panel.partition("!")[0] for panel in layout["configById"])
    assert kinds == ["3D", "Plot", "Plot", "RawMessages"]


def test_the_3d_panel_shows_the_demos_frames_and_one_of_them_moves() -> None:
    config = demo()
    frames = Frames({n["address"]: n.get("name") for n in config["nodes"]}.get)
    moving = [n for n in config["nodes"] if frames.maker(n["address"], n["stream"])]
    assert moving, "the demo streams no orientation: the 3D panel would stand still"
    (scene,) = (c for p, c in json.loads(LAYOUT.read_text())["configById"].items()
                if p.startswith("3D!"))
    assert scene["followTf"] == PARENT_FRAME
    shown = {name.removeprefix("frame:") for name in scene["transforms"]}
    named = {child_frame(n["address"], n.get("name")) for n in config["nodes"]}
    assert shown == named | {PARENT_FRAME}
    assert {f"gx2/{n['address']}/frame" for n in moving} <= set(scene["topics"])


def test_the_plots_are_of_fields_the_demo_publishes() -> None:
    streamed = {f"gx2/{n['address']}/{n['stream']}" for n in demo()["nodes"]}
    plotted: set[str] = set()
    for panel, config in json.loads(LAYOUT.read_text())["configById"].items():
        if panel.startswith("Plot!"):
            for path in config["paths"]:
                found = PATH.match(path["value"])
                assert found, path["value"]
                assert found["topic"] in streamed, found["topic"]
                schema = schema_for_topic(found["topic"])[1]  # type: ignore[index]
                field = schema["properties"][found["field"]]
                assert int(found["index"]) < field["maxItems"]
                plotted.add(found["field"])
        elif panel.startswith("RawMessages!"):
            assert config["topicPath"] == "gx2/gateway/status"
    assert plotted == {"accel", "ang_rate"}


def test_the_wheel_ships_it_beside_the_configurations() -> None:
    data = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"]["gateway"]
    shipped = REPO / "gateway"
    assert any(LAYOUT.name in {p.name for p in shipped.glob(pattern)} for pattern in data)

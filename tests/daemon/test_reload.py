"""What a reload would do (:func:`gateway.daemon.reload.plan`): the nodes added, removed
and changed, and everything else refused naming the key that needs a restart."""

from __future__ import annotations

from typing import Any

import pytest

from gateway.daemon.config import GatewayConfig
from gateway.daemon.reload import NeedsRestart, plan


def config(nodes: list[dict[str, Any]] | None = None, **keys: Any) -> GatewayConfig:
    data: dict[str, Any] = {"base_station": {"port": "/dev/ttyUSB0"},
                            "nodes": nodes or [{"address": 76, "stream": "euler"},
                                               {"address": 77}]}
    data.update(keys)
    return GatewayConfig.model_validate(data)


def two(north: list[dict[str, Any]], south: list[dict[str, Any]],
        south_port: str = "/dev/ttyUSB1", **keys: Any) -> GatewayConfig:
    return GatewayConfig.model_validate({"base_stations": [
        {"name": "north", "port": "/dev/ttyUSB0", "nodes": north},
        {"name": "south", "port": south_port, "nodes": south}], **keys})


def said(before: GatewayConfig, after: GatewayConfig) -> dict[str, list[int]]:
    todo = plan(before, after)
    return {"added": [e.address for _, e in todo.added],
            "removed": [a for _, a in todo.removed],
            "changed": [e.address for _, e in todo.changed]}


def test_the_same_file_changes_nothing():
    todo = plan(config(), config())
    assert not todo and todo.said() == "nothing changed"


def test_nodes_added_removed_and_changed():
    after = config([{"address": 76, "stream": "accel_angrate"}, {"address": 78}])
    assert said(config(), after) == {"added": [78], "removed": [77], "changed": [76]}
    assert plan(config(), after).touched == {76, 77}  # (78 is no running node)


def test_a_name_or_gyro_is_a_change():
    after = config([{"address": 76, "stream": "euler", "name": "wing"}, {"address": 77}])
    assert said(config(), after) == {"added": [], "removed": [], "changed": [76]}


def test_a_node_moved_between_stations_is_removed_from_one_and_added_to_the_other():
    before = two([{"address": 76}], [{"address": 78}])
    after = two([{"address": 76}, {"address": 78}], [{"address": 79}])
    todo = plan(before, after)
    assert [(s, e.address) for s, e in todo.added] == [("north", 78), ("south", 79)]
    assert todo.removed == (("south", 78),) and not todo.changed


def test_the_one_station_form_and_a_list_of_one_are_the_same_station():
    listed = GatewayConfig.model_validate({"base_stations": [
        {"port": "/dev/ttyUSB0", "nodes": [{"address": 76, "stream": "euler"},
                                           {"address": 77}]}]})
    assert not plan(config(), listed)


@pytest.mark.parametrize(("keys", "named"), [
    ({"publish": {"endpoint": "tcp://127.0.0.1:6000"}}, "publish.endpoint"),
    ({"control": {"allow_eeprom_write": True}}, "control.allow_eeprom_write"),
    ({"record": {"directory": "/tmp/elsewhere"}}, "record"),
    ({"health": {"window_s": 30}}, "health.window_s"),
    ({"base_station": {"port": "/dev/ttyUSB9"}}, "base_station.port"),
    ({"base_station": {"port": "/dev/ttyUSB0", "baudrate": 9600}}, "base_station.baudrate"),
])
def test_what_cannot_change_live_is_refused_naming_its_key(keys, named):
    # a node added beside it changes nothing: all or nothing
    after = config([{"address": 76, "stream": "euler"}, {"address": 77}, {"address": 78}],
                   **keys)
    with pytest.raises(NeedsRestart, match="restart") as refused:
        plan(config(), after)
    assert str(refused.value).startswith(f"{named} cannot change")


def test_a_station_of_several_is_named_by_its_place_and_stations_are_fixed():
    before = two([{"address": 76}], [{"address": 78}])
    with pytest.raises(NeedsRestart, match=r"^base_stations\[1\]\.port "):
        plan(before, two([{"address": 76}], [{"address": 78}], south_port="/dev/ttyUSB2"))
    one = GatewayConfig.model_validate({"base_stations": [
        {"name": "north", "port": "/dev/ttyUSB0", "nodes": [{"address": 76}]}]})
    with pytest.raises(NeedsRestart, match="base stations"):
        plan(before, one)


def test_the_nodes_of_a_simulated_station_need_a_restart_and_others_do_not():
    before = two([{"address": 76}], [{"address": 78}], south_port="sim://")
    after = two([{"address": 76}, {"address": 77}], [{"address": 78}], south_port="sim://")
    assert said(before, after)["added"] == [77]
    with pytest.raises(NeedsRestart, match=r"base_stations\[1\]\.nodes .*sim://"):
        plan(before, two([{"address": 76}], [{"address": 79}], south_port="sim://"))

"""deploy/grafana-gx2.json, the Grafana dashboard: a dashboard Grafana imports (its JSON
model, a Prometheus datasource variable, the gateway variables), every query of which
names only metrics and labels a running gateway serves, and parses as PromQL."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import urllib.request
from pathlib import Path
from typing import Any

import pytest
import yaml
from prometheus_client.parser import text_string_to_metric_families

from tests.e2e.test_stations import two_stations
from tests.helpers.waiting import wait_for

DASHBOARD = Path(__file__).resolve().parents[2] / "deploy" / "grafana-gx2.json"
METRIC = re.compile(r"\bgx2_[a-z_]+")
MATCHER = re.compile(r"(\w+)\s*(?:=~|!~|!=|=)\s*\"")
GROUPING = re.compile(r"\b(?:by|without|on|ignoring|group_left|group_right)\s*\(([^)]*)\)")
LEGEND = re.compile(r"\{\{\s*(\w+)\s*\}\}")
ADDED_BY_PROMETHEUS = {"job", "instance"}
VARIABLES = {"$__rate_interval": "1m", "$job": ".*", "$instance": ".*", "$node": ".*"}


def dashboard() -> dict[str, Any]:
    return json.loads(DASHBOARD.read_text())


def queries() -> list[tuple[str, str, str]]:
    """(panel title, expression, legend) of every query of every panel."""
    return [(panel["title"], target["expr"], target.get("legendFormat", ""))
            for panel in dashboard()["panels"] for target in panel.get("targets", ())]


def variable_queries() -> list[str]:
    return [variable["definition"] for variable in dashboard()["templating"]["list"]
            if variable["type"] == "query"]


def filled(expression: str) -> str:
    """The expression as Grafana sends it, its variables given values."""
    for name, value in VARIABLES.items():
        expression = expression.replace(name, value)
    assert "$" not in expression, expression
    return expression


def served(endpoint: str) -> dict[str, set[str]]:
    """Every sample name a gateway's /metrics serves, with its label names."""
    with urllib.request.urlopen(f"http://{endpoint}/metrics", timeout=5) as response:
        text = response.read().decode()
    names: dict[str, set[str]] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            names.setdefault(sample.name, set()).update(sample.labels)
    return names


def test_the_dashboard_is_a_grafana_model_with_a_gateway_variable() -> None:
    model = dashboard()
    assert model["uid"] and model["title"] and model["schemaVersion"] >= 36
    variables = {v["name"]: v for v in model["templating"]["list"]}
    assert variables["datasource"]["type"] == "datasource"
    assert variables["datasource"]["query"] == "prometheus"
    assert variables["instance"]["multi"] and variables["instance"]["includeAll"]
    ids = [panel["id"] for panel in model["panels"]]
    assert len(ids) == len(set(ids))
    for panel in model["panels"]:
        if panel["type"] == "row":
            continue
        assert panel["datasource"]["uid"] == "${datasource}", panel["title"]
        assert panel["targets"], panel["title"]
        for target in panel["targets"]:
            # every query follows the gateway variables, so several gateways share it
            assert 'instance=~"$instance"' in target["expr"], (panel["title"], target)
    shown = " ".join(expr for _, expr, _ in queries())
    for metric in ("gx2_link_bytes_per_second", "gx2_gateway_health", "gx2_link_up",
                   "gx2_node_rate_hz", "gx2_node_lost_radio_total",
                   "gx2_node_lost_gateway_total", "gx2_node_rssi_dbm", "gx2_node_lqi",
                   "gx2_node_clock_drift_ppm", "gx2_recording_bytes",
                   "gx2_recording_errors_total"):
        assert metric in shown, metric


def test_every_metric_and_label_the_dashboard_names_is_served(simulator, gateway,
                                                              tmp_path) -> None:
    _, _, gw = two_stations(simulator, gateway, metrics={},
                            record={"directory": str(tmp_path / "recordings")})
    endpoint = gw.config["metrics"]["endpoint"]
    # (a node's clock floor's age is served once its clock estimate has locked)
    metrics = wait_for(lambda: (m := served(endpoint)).get(
        "gx2_node_clock_floor_age_seconds") and m, 30, "the nodes' clocks to lock")
    assert "gx2_link_up" in metrics and "station" in metrics["gx2_link_up"]
    for title, expression, legend in queries() + [
            ("variable", query, "") for query in variable_queries()]:
        names = METRIC.findall(expression)
        assert names, (title, expression)
        labels_of_any: set[str] = set()
        for name in names:
            assert name in metrics, f"{title}: {name} is not served"
            labels_of_any |= metrics[name]
        for selector in re.findall(r"gx2_[a-z_]+\{([^}]*)\}", expression):
            name = re.search(rf"(gx2_[a-z_]+)\{{{re.escape(selector)}\}}", expression)[1]
            for label in set(MATCHER.findall(selector)) - ADDED_BY_PROMETHEUS:
                assert label in metrics[name], f"{title}: {name} has no label {label}"
        grouped = {label.strip() for labels in GROUPING.findall(expression)
                   for label in labels.split(",") if label.strip()}
        for label in (grouped | set(LEGEND.findall(legend))) - ADDED_BY_PROMETHEUS:
            assert label in labels_of_any, f"{title}: no metric of {expression} has {label}"


@pytest.mark.skipif(shutil.which("promtool") is None,
                    reason="promtool is not installed (Debian: apt-get install prometheus)")
def test_promtool_parses_every_query(tmp_path: Path) -> None:
    """Each query, its variables filled in as Grafana fills them, as a recording rule
    promtool checks (offline: it parses each expression)."""
    rules = [{"record": f"gx2:dashboard_query_{number}", "expr": filled(expression)}
             for number, (_, expression, _) in enumerate(queries())]
    path = tmp_path / "dashboard-rules.yml"
    path.write_text(yaml.safe_dump({"groups": [{"name": "dashboard", "rules": rules}]}))
    run = subprocess.run(["promtool", "check", "rules", str(path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"{len(rules)} rules found" in run.stdout, run.stdout

"""A trial's export says which trial it is: ``trial.json`` beside its tables, with the
fields of its start mark (``gx2ctl mark --field``), by gx2ctl's entry point in process
(the installed program exports trials in tests/e2e/test_windows_recorded.py)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.helpers.processes import gx2ctl_here
from tests.helpers.recorded import foreign_file

T0 = 1_795_000_000.0


def test_each_trials_export_has_its_trial_json(tmp_path: Path) -> None:
    def mark(at: float, text: str, **fields: str) -> tuple[str, dict]:
        return ("gx2/gateway/mark", {"time": T0 + at, "host_time": T0 + at, "nodes": [],
                                     "text": text, "fields": fields})
    entries = [mark(1, "start", subject="S01", condition="fast"), mark(3, "stop"),
               mark(5, "start", subject="S02"), mark(7, "stop")]
    for i in range(80):
        entries.append(("gx2/11/euler", {"node": 11, "record": "euler", "seq": i,
                                         "host_time": T0 + i / 10, "roll": 0.1,
                                         "pitch": 0.2, "yaw": 0.3}))
    entries.sort(key=lambda e: e[1]["host_time"])
    path = foreign_file(tmp_path / "study.mcap", entries)
    ran = gx2ctl_here("export", str(path), "--out", str(tmp_path / "out"), "--between-marks",
                      "start", "stop")
    assert ran.status == 0, ran
    found = sorted((tmp_path / "out").glob("trial-*/trial.json"))
    assert [json.loads(p.read_text()) for p in found] == [
        {"trial": 1, "start": T0 + 1, "stop": T0 + 3, "start_mark": "start",
         "stop_mark": "stop", "fields": {"subject": "S01", "condition": "fast"}},
        {"trial": 2, "start": T0 + 5, "stop": T0 + 7, "start_mark": "start",
         "stop_mark": "stop", "fields": {"subject": "S02"}}]
    assert f"{found[1]}  trial 2\n" in ran.stdout
    listed = json.loads(gx2ctl_here("trials", "--json", str(path)).stdout)["trials"]
    assert [t["fields"] for t in listed] == [{"subject": "S01", "condition": "fast"},
                                             {"subject": "S02"}]
    assert [t["nodes"] for t in listed] == [{"11": {"euler": 21}}] * 2

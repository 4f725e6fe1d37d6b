"""The fault soak of bench/faultsoak.py, three minutes on a fixed seed: the installed
gateway on gx2-sim through a host stall, an unplug, one node's power cycle and all
three's, a burst of radio loss, a load change, an overload and a reload, each record's
``time`` against the instant the simulated node really took the sample. What a user
relies on: the gateway recovers within its health window after each fault, the samples
``time`` is off for are warned of, every ``late_ms`` status gives is a bound, and the
gateway loses nothing. (The bench's other kinds run
elsewhere in the suite: a CPU hog would slow every other test, the MQTT broker's
restart is tests/e2e/test_mqtt.py's, the full disk tests/e2e/test_recording_failures.py's.)

``time`` outside the faults' windows and the needless WARN's share are the bench's
figures, not asserted here: three minutes hold too few quiet stretches for a median
(gx2-sim powers its nodes up together, and their packets queue behind each other's
for tens of seconds as their crystals slide past: issue 32's limit).

The health window is made short (8 s) so that eight faults and their recoveries fit in
three minutes; the recovery bound follows it (bench/faultsoak.py, RECOVERY_SLACK). The
module runs first in the suite (tests/conftest.py, FIRST), beside the rest."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from gateway.recording.writer import RecordingWriter
from tests.helpers.processes import favoured

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
try:
    import faultsoak
    import soakreport
finally:
    sys.path.pop(0)

SEED = 3
KINDS = ("stall", "unplug", "power_one", "power_all", "radio", "load", "overload", "reload")
MINUTES = 3.0


@pytest.fixture(scope="module")
def report() -> soakreport.Report:
    # (favoured: the soak measures the gateway as a host with a core to spare runs it;
    # beside 3 other test processes on 2 cores, the first samples after a line locked
    # were 0.50 to 0.53 ms off, unwarned, and the run failed on them)
    with favoured():
        result = faultsoak.run(MINUTES * 60, SEED, kinds=KINDS, window_s=8.0,
                               settle_s=3.0, quiet=(2.0, 4.0))
    assert {f.kind for f in result.faults} == set(KINDS), result.faults
    report = soakreport.analyse(result)
    soakreport.print_report(result, report)  # (pytest shows it when a test fails)
    return report


# "off samples warned": at least 95% of the samples more than 0.5 ms off come under a
# clock or line WARN. In one full run (of two) before the young fit's allowance
# (aspp.clock.held_drift_error), an overload in the run's first minute held clocks
# whose drift had been fitted for under a minute, and time went 3.7 ms off under an
# allowance under 0.5 ms: 93.4%. Since, beside a second soak and a CPU hog on this
# 2-core machine: 96.8% and 98.9% (the rest in a replug's first second, 5 s into the run,
# before a stream is judged, health.settle_s, and the overload's first moments).
@pytest.mark.parametrize("invariant", ["recovery", "off samples warned", "late_ms a bound",
                                       "nothing lost in the gateway"])
def test_the_gateway_holds_through_ordinary_faults(report: soakreport.Report,
                                                   invariant: str) -> None:
    ok, figures = report.invariants[invariant]
    assert ok, f"{invariant}: {figures}\n" + "\n".join(report.lines)


def test_the_soaks_recording_check_reads_a_file_cut_short_up_to_where_it_stops(tmp_path):
    """A full disk cuts the file being written back to its last flush, and one whose
    end the disk refused stops there: its records before that are the recording's, and
    the check must count them (it once read none of such a file: 2,408 "missing")."""
    path = tmp_path / "cut.mcap"
    with path.open("xb") as out:
        writer = RecordingWriter(out, {})
        for seq in range(1, 301):
            writer.message("gx2/76/accel_angrate",
                           {"node": 76, "seq": seq, "host_time": 1.7e9 + seq / 100}, None,
                           (1.7e9 + seq / 100, 1.7e9 + seq / 100))
            if seq % 100 == 0:
                writer.flush()
        kept = writer._kept_at  # (the last flush: where a cut file is cut back to)
        out.flush()
    os.truncate(path, kept)
    recorded = faultsoak.Recorded()
    recorded.read([path])
    assert len(recorded.hashes) == 300 and len(recorded.cut) == 1, recorded.cut

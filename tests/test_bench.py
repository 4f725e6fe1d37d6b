"""The hand-run benchmarks still run against this tree: a small round of perf.py's
pipeline (the daemon's read callback, a SUB in another process counting every record),
so a layout change that breaks a benchmark's imports fails here, not months later when
someone needs the figure."""

from __future__ import annotations

import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "bench"


def test_perf_pipeline_round_runs_and_every_record_arrives() -> None:
    sys.path.insert(0, str(BENCH))
    try:
        from decoder_throughput import mixed_stream
        from perf import pipeline_round
    finally:
        sys.path.remove(str(BENCH))
    stream = mixed_stream(3000)
    chunks = [stream[o:o + 4096] for o in range(0, len(stream), 4096)]
    per_cpu, per_wall = pipeline_round(chunks, 3000)  # asserts the SUB got all 3000
    assert per_cpu > 0 and per_wall > 0

"""What ``gx2ctl scan`` prints of a node read only in part: nothing guessed."""

from __future__ import annotations

from gateway.ctl.scan import found_line

READ = {"address": 81, "station": "station1", "lqi": 200, "rssi": -45,
        "model_name": "Inertia-Link", "serial_number": "4200-0081",
        "firmware_version": "2.1.13", "divider": 512, "rate_hz": 100.0,
        "streaming": "euler", "configured": False}


def test_a_start_up_setting_not_read_is_unknown_not_none():
    line = found_line({**READ, "auto_start": None,
                       "unanswered": "out of time before every read was answered"})
    assert "streaming euler (from power-up: unknown)" in line
    assert "answers pings, not every read: out of time" in line


def test_a_start_up_setting_read_as_none_says_none():
    line = found_line({**READ, "auto_start": None, "unanswered": None})
    assert "streaming euler (from power-up: none)" in line
    assert "not every read" not in line

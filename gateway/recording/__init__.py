"""Recordings: MCAP files of what a gateway read, wrote and published
(:mod:`~gateway.recording.files`, `.writer`, `.reader`), and what gx2ctl makes of them: tables
(:mod:`~gateway.recording.export`) and pictures (:mod:`~gateway.recording.plot`)."""

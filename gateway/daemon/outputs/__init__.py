"""Where published messages go: ZeroMQ (:mod:`.zeromq`), the MCAP recorder
(:mod:`.recorder`), the Foxglove live view (:mod:`.live`), Prometheus metrics
(:mod:`.metrics`). An output never calls back into a station."""

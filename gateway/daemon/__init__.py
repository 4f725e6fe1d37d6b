"""gx2-gateway: the daemon that owns the base station's serial port, publishes every
node's records over ZeroMQ and answers control requests (:mod:`.app` wires it)."""

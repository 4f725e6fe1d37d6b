"""gx2ctl: the ops tool that talks to a running gx2-gateway. It imports no pydantic
(only ``--config`` loads the gateway's own configuration validator), so it starts fast."""

PROG = "gx2ctl"

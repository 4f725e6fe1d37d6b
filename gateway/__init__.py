"""The three programs of gx2-gateway, and what they share.

- :mod:`gateway.daemon`: ``gx2-gateway``, which owns the base station's port;
- :mod:`gateway.ctl`: ``gx2ctl``, the ops tool that talks to a running gateway;
- :mod:`gateway.sim`: ``gx2-sim``, a base station and its nodes behind a pty;
- :mod:`gateway.common`: what all three share.

The protocol itself is :mod:`aspp`, which does no I/O.
"""

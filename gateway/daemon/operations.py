"""What each control op does: one async function per row of the op table
(:mod:`gateway.common.ops`), registered under the row's name with
:func:`~.opcontext.handles`, and what they run against (:class:`Operations`).

Importing this module makes the table whole: the ops of a step or two
(:mod:`.nodeops`), those that measure, correct and check what a node senses
(:mod:`.calibration`), and the scan (:mod:`.scanning`) register themselves as they are
imported. Each imports :mod:`.opcontext`, never this module: no import loop.
"""

from __future__ import annotations

from . import calibration, nodeops, scanning  # noqa: F401  (each registers its ops)
from .opcontext import HANDLERS, Operations, Result, StationParts, handles

__all__ = ["HANDLERS", "Operations", "Result", "StationParts", "handles"]

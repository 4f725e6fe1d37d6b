"""The exceptions the protocol library raises: for misuse and invalid arguments only.

Corrupt bytes on the line never raise; the decoder reports them as events.
"""


class AsppError(ValueError):
    """Base of every error this library raises on purpose."""


class PacketError(AsppError):
    """A packet, or an argument to a packet builder, is not valid."""


class CommandError(AsppError):
    """A GX2 command cannot be built or parsed; the message names the argument."""


class RecordError(AsppError):
    """Reply bytes are not a record this library can decode (unknown command, or a
    length that does not match the record's layout)."""


class ClockStateError(AsppError):
    """An event a node's clock estimate does not take in its state (a release with no
    hold, a hold on a hold): the caller's bug (:mod:`aspp.clockstate`)."""

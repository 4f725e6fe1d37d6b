"""The gateway's base stations, and the one map of which node is on which.

Everything that asks "which station is node N on?" (the operations, the gateway's
status, its health) reads it here: built when the stations are, and changed only by a
reload (:mod:`.reload`), in place, so every holder of its maps sees the change.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from typing import Generic, Protocol, TypeVar, overload

from .station.nodes import Node


class HasNodes(Protocol):
    @property
    def nodes(self) -> dict[int, Node]: ...
    @property
    def replaying(self) -> bool: ...


S = TypeVar("S", bound=HasNodes)


class Stations(Sequence[S], Generic[S]):
    """The stations in their configured order (the first is a one-station gateway's
    only one), every node by address, and each node's station."""

    def __init__(self, stations: Iterable[S]) -> None:
        self._all = list(stations)
        self.of: dict[int, S] = {address: station for station in self._all
                                 for address in station.nodes}
        """Node address -> the station it is on."""
        self.nodes: dict[int, Node] = {address: node for station in self._all
                                       for address, node in station.nodes.items()}
        """Node address -> its state, every station's."""
        self.replaying = any(station.replaying for station in self._all)
        """Some station plays a recording: nothing may be sent to a node."""

    def add(self, station: S, node: Node) -> None:
        """``node`` is on ``station`` from now on (a reload added it)."""
        self.of[node.address] = station
        self.nodes[node.address] = node

    def remove(self, address: int) -> Node:
        """Node ``address`` is on no station any more (a reload removed it): its state."""
        del self.of[address]
        return self.nodes.pop(address)

    @overload
    def __getitem__(self, index: int) -> S: ...
    @overload
    def __getitem__(self, index: slice) -> list[S]: ...
    def __getitem__(self, index: int | slice) -> S | list[S]:
        return self._all[index]

    def __len__(self) -> int:
        return len(self._all)

    def __iter__(self) -> Iterator[S]:
        return iter(self._all)

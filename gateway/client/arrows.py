"""A Recording's records as one pyarrow Table, the shape of :func:`.frames.to_pandas`
(a row per record in the order read; its columns, the record's fields in export's
columns after them), made a batch at a time by export's columnar path
(:mod:`gateway.recording.columnar`: a batch's JSON decoded in one call, each column
typed as ``export --format parquet`` types it, its meaning and unit in the field's
metadata), not a Message and a dict per record: the same values, at a fraction of the
cost (bench/window.py).

``time`` and ``host_time`` are ``timestamp[ns, UTC]`` and ``device_time``
``duration[ns]``, to the nanosecond the message wrote; what the recording holds as null
(a NaN sample) is null, as in export's Parquet; ``gateway`` and ``record`` are
dictionary-encoded text (a row's name costs 4 bytes, not the name). ``gap`` and
``restarted`` are the iteration's (:class:`.messages.Numbering`): each node's ``seq``
followed over every record, those ``records`` leaves out too, a window at a time.

A batch the one-call path cannot take as a message is read one at a time (one that is
not a record's JSON object or has no integer ``seq``, a file of before the matrix's
derived fields) is taken message by message through the iteration's steps: slower,
never different. A Recording whose ``time`` is refined is taken from its loop (the
refinement is handed out message by message), ``time_placed`` and ``time_bound_ms``
after ``time`` as in to_pandas.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from aspp.records import DERIVED_FROM_MATRIX
from gateway.common.payloads import MATRIX, as_published
from gateway.common.topics import parse
from gateway.recording.batchsteps import NONE
from gateway.recording.columnar import Columns
from gateway.recording.columns import record_columns
from gateway.recording.files import STATUS, RecordingError
from gateway.recording.parquetfile import BATCH, MissingExtra, arrow_schema
from gateway.recording.reader import Entry
from gateway.recording.tables import BOUND, PLACED, field_columns
from gateway.recording.window import Reader

from .frames import LEADING
from .messages import Malformed, Message, seq_of

if TYPE_CHECKING:
    import pyarrow

Recording = Any
"""A :class:`.recorded.Recording` (not imported: it imports this module to make its
table, and the two would import each other round a loop, tests/ctl/test_imports.py)."""

INSTALL_ARROW = "pip install 'gx2-gateway[arrow]'"
BOOKKEEPING = ("time", "host_time", "device_time", "seq", "lqi", "rssi")
"""The columns of LEADING that export's columnar path reads from each message."""
REFINED = (*LEADING[:LEADING.index("time") + 1], PLACED, BOUND,
           *LEADING[LEADING.index("time") + 1:])
"""LEADING of a Recording whose time is refined: export's two columns after ``time``,
as to_pandas has them."""
REFINED_BOOKKEEPING = (BOOKKEEPING[0], PLACED, BOUND, *BOOKKEEPING[1:])
DERIVED = frozenset(field.name for field in DERIVED_FROM_MATRIX)
POSITION = "position"
"""Each row's place in the order read (the rows are put back in it, then it goes)."""


def _pyarrow() -> Any:
    try:
        import pyarrow
        import pyarrow.compute
    except ImportError:
        raise MissingExtra(f"to_arrow needs pyarrow: {INSTALL_ARROW}") from None
    return pyarrow


class _Part:
    """A batch of one topic's records, decoded: where each was read, its ``seq``, its
    ``gap`` and ``restarted`` once its window is numbered, its rows (None: a record
    left out, numbered only)."""

    def __init__(self, node: int, record: str, positions: np.ndarray, seq: np.ndarray,
                 table: Any) -> None:
        self.node, self.record, self.positions, self.seq = node, record, positions, seq
        self.table = table
        self.gap = np.zeros(len(seq), np.int64)
        self.restarted = np.zeros(len(seq), bool)


class _Topic:
    """One topic's messages waiting for a batch, and how they become columns."""

    def __init__(self, recording: Recording, topic: str, node: int, record: str,
                 first: dict[str, Any]) -> None:
        self.recording, self.topic, self.node, self.record = recording, topic, node, record
        self.wanted = not recording.records or record in recording.records
        fields = field_columns(record, first)
        self.columns = Columns(topic, record_columns(record, BOOKKEEPING, fields, first),
                               fields, BOOKKEEPING)
        self.matrix = [c for c, field, _ in fields if field == MATRIX]
        self.derived = [c for c, field, _ in fields if field in DERIVED]
        self.messages: list[bytes] = []
        self.positions: list[int] = []

    def add(self, data: bytes, position: int) -> _Part | None:
        self.messages.append(data)
        self.positions.append(position)
        return self.decoded() if len(self.messages) >= BATCH else None

    def decoded(self) -> _Part | None:
        """The messages waiting, as a part (None if none)."""
        if not self.messages:
            return None
        messages, positions = self.messages, np.array(self.positions, np.int64)
        self.messages, self.positions = [], []
        try:
            batch = self.columns.batch(messages, [0] * len(messages))
        except RecordingError:  # (a message that is not a JSON object)
            return self._one_by_one(messages, positions)
        if (batch.rows.seq == NONE).any() or self._underived(batch.table):
            return self._one_by_one(messages, positions)
        return _Part(self.node, self.record, positions, batch.rows.seq,
                     batch.table if self.wanted else None)

    def _underived(self, table: Any) -> bool:
        """A row with the matrix whole and a derived field null: a file of before they
        were recorded, derived by :func:`.payloads.as_published` from the matrix."""
        if not self.matrix or not self.derived:
            return False
        import pyarrow.compute as pc
        whole = table[self.matrix[0]].is_valid()
        for column in self.matrix[1:]:
            whole = pc.and_(whole, table[column].is_valid())
        for column in self.derived:
            if pc.any(pc.and_(whole, table[column].is_null())).as_py():
                return True
        return False

    def _one_by_one(self, messages: list[bytes], positions: np.ndarray) -> _Part:
        """The batch as the iteration reads each message (what it skips, skipped and
        counted likewise)."""
        payloads, seqs, kept = [], [], []
        for data in messages:
            try:
                payload = as_published(Entry(self.topic, 0, 0, data).payload())
                seq = seq_of(payload, self.topic)
                if not -(2 ** 63) <= seq < 2 ** 63:  # (beyond an int64 column)
                    raise Malformed(f"on {self.topic}: seq {seq} beyond 64 bits")
            except (RecordingError, Malformed) as problem:
                self.recording.skipped(problem)
                kept.append(False)
                continue
            payloads.append(payload)
            seqs.append(seq)
            kept.append(True)
        table = self.columns.rows(payloads) if self.wanted else None
        return _Part(self.node, self.record, positions[np.array(kept, bool)],
                     np.array(seqs, np.int64), table)


def to_arrow(recording: Recording) -> pyarrow.Table:
    """The records of ``recording`` (its windows, nodes and records) as one Table;
    MissingExtra, saying how to install it, without pyarrow."""
    pa = _pyarrow()
    if recording.time == "refined":
        return _refined(pa, recording)
    reader = Reader(recording.files, recording.reading)
    topics: dict[str, _Topic | None] = {}
    wanted: list[_Part] = []
    position = 0
    try:
        for window in recording.windows:
            recording._numbering.forget()  # (what lies between windows is not lost)
            parts: list[_Part] = []
            for entry in reader.entries(window):
                topic = entry.topic
                if topic == STATUS:
                    if recording.yield_status:
                        recording.numbered_status(entry)
                    continue
                waiting = topics.get(topic) if topic in topics else _opened(
                    recording, topics, entry)
                if waiting is None:
                    continue
                part = waiting.add(entry.data, position)
                position += 1
                if part is not None:
                    parts.append(part)
            parts += [p for p in (t.decoded() for t in topics.values() if t) if p]
            _numbered(recording, parts)
            wanted += [part for part in parts if part.table is not None]
    finally:
        recording.duplicates += reader.duplicates
    return _joined(pa, recording.source, wanted, LEADING)


class _Loop:
    """One topic's messages as the loop gave them, waiting for a batch."""

    def __init__(self, message: Message) -> None:
        self.node, self.record = message.node, message.record
        fields = field_columns(message.record, dict(message.payload))
        self.columns = Columns(f"gx2/{self.node}/{self.record}", record_columns(
            self.record, REFINED_BOOKKEEPING, fields, dict(message.payload)), fields,
            REFINED_BOOKKEEPING)
        self.messages: list[Message] = []
        self.positions: list[int] = []

    def add(self, message: Message, position: int) -> _Part | None:
        self.messages.append(message)
        self.positions.append(position)
        return self.part() if len(self.messages) >= BATCH else None

    def part(self) -> _Part:
        messages, self.messages = self.messages, []
        part = _Part(self.node, self.record, np.array(self.positions, np.int64),
                     np.array([m.seq for m in messages], np.int64),
                     self.columns.rows([dict(m.payload) for m in messages]))
        part.gap = np.array([m.gap for m in messages], np.int64)
        part.restarted = np.array([m.restarted for m in messages], bool)
        self.positions = []
        return part


def _refined(pa: Any, recording: Recording) -> Any:
    """A Recording whose time is refined: the loop's messages (the refinement is handed
    out message by message, as ``export --time refined`` goes row by row), each
    topic's typed as export types them, a batch at a time."""
    topics: dict[tuple[int, str], _Loop] = {}
    parts: list[_Part] = []
    messages = (event for event in recording if isinstance(event, Message))
    for position, message in enumerate(messages):
        key = (message.node, message.record)
        held = topics.get(key) or topics.setdefault(key, _Loop(message))
        part = held.add(message, position)
        if part is not None:
            parts.append(part)
    parts += [held.part() for held in topics.values() if held.messages]
    return _joined(pa, recording.source, parts, REFINED)


def _opened(recording: Recording, topics: dict[str, _Topic | None], entry: Entry
            ) -> _Topic | None:
    """A topic's first message: its table's columns (None: not a node's record; a
    first message that is not a JSON object, skipped, as the iteration skips it)."""
    where = parse(entry.topic)
    if where is None:
        topics[entry.topic] = None
        return None
    try:
        first = as_published(entry.payload())
    except RecordingError as problem:
        recording.skipped(problem)
        return None
    found = topics[entry.topic] = _Topic(recording, entry.topic, *where, first)
    return found


def _numbered(recording: Recording, parts: list[_Part]) -> None:
    """The window's ``gap`` and ``restarted``, as :meth:`.messages.Numbering.count`
    gives them message by message: each node's ``seq`` in the order read."""
    nodes: dict[int, list[_Part]] = {}
    for part in parts:
        nodes.setdefault(part.node, []).append(part)
    for node, held in nodes.items():
        seq = np.concatenate([p.seq for p in held])
        order = np.argsort(np.concatenate([p.positions for p in held]), kind="stable")
        ordered = seq[order]
        gap = np.zeros(len(seq), np.int64)
        restarted = np.zeros(len(seq), bool)
        step = ordered[1:] - ordered[:-1]
        gap[order[1:]] = np.where(step > 0, step - 1, 0)
        restarted[order[1:]] = step <= 0
        at = 0
        for part in held:
            part.gap, part.restarted = gap[at:at + len(part.seq)], restarted[
                at:at + len(part.seq)]
            at += len(part.seq)
        lost = int(gap.sum())
        if lost:
            key = (recording.source, node)
            recording.lost[key] = recording.lost.get(key, 0) + lost


def _joined(pa: Any, source: str, parts: list[_Part], first: tuple[str, ...]) -> Any:
    """The parts as one table: ``first`` (LEADING, or REFINED), then each record's
    fields as they first come, the rows in the order read."""
    import pyarrow.compute as pc
    leading = _leading(pa, first)
    names = list(first)
    tables = []
    for part in sorted((p for p in parts if len(p.seq)), key=lambda p: p.positions[0]):
        table, n = part.table, len(part.seq)
        names += [name for name in table.column_names if name not in names]
        made = {"gateway": _text(pa, source, n), "node": pa.repeat(pa.scalar(
            part.node, pa.int64()), n), "record": _text(pa, part.record, n),
                "gap": pa.array(part.gap), "restarted": pa.array(part.restarted)}
        columns = [(leading.field(name), made[name]) if name in made else
                   (table.schema.field(name), table[name]) for name in first]
        columns += [(field, table[field.name]) for field in table.schema
                    if field.name not in first]
        columns.append((pa.field(POSITION, pa.int64()), pa.array(part.positions)))
        tables.append(pa.Table.from_arrays([c for _, c in columns],
                                           schema=pa.schema([f for f, _ in columns])))
    if not tables:  # (as to_pandas: the columns every row has)
        return _leading(pa, LEADING).empty_table()
    whole = pa.concat_tables(tables, promote_options="permissive")
    return whole.take(pc.sort_indices(whole[POSITION])).select(names)


def _leading(pa: Any, first: tuple[str, ...]) -> Any:
    """The fields of ``first``: the bookkeeping as export types it, the rest the
    iteration's."""
    read = arrow_schema(pa, record_columns("", REFINED_BOOKKEEPING, [], {}))
    text = pa.dictionary(pa.int32(), pa.string())
    own = {"gateway": text, "node": pa.int64(), "record": text, "gap": pa.int64(),
           "restarted": pa.bool_()}
    return pa.schema([pa.field(name, own[name]) if name in own else read.field(name)
                      for name in first])


def _text(pa: Any, value: str, rows: int) -> Any:
    return pa.DictionaryArray.from_arrays(pa.array(np.zeros(rows, np.int32)),
                                          pa.array([value]))

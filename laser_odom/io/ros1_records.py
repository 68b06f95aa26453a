"""A tolerant, sequential reader of ROS 1 bag (format 2.0) records.

rosbags' ROS 1 reader starts from the index at the end of the file, so it refuses bags
whose index is missing (a recording cut short) or non-standard (some old bags declare
index-data lengths that do not match their entry count). The records themselves are
self-delimiting, so this reader walks them from the start instead (ROS bag format 2.0,
http://wiki.ros.org/Bags/Format/2.0): every record is ``<header_len><header>
<data_len><data>``, a header is a list of ``<len>name=value`` fields, and the ``op``
field says what the record is. Chunk records hold the connection and message-data
records; they are decompressed (none, bz2, lz4) and walked in turn.

Where a declared length disagrees with the record's own entry count (index data: 12
bytes per entry; chunk info: 8 bytes per entry), the length after which the next
record header parses is taken. A record cut off by the end of the file ends reading
with :class:`RecordReadError`; messages of a partly present, uncompressed (or
stream-decodable) chunk that are complete are still delivered first.
"""

from __future__ import annotations

import bz2
from dataclasses import dataclass
from pathlib import Path
import struct
from typing import BinaryIO, Callable, Iterator

import lz4.frame

MAGIC = b'#ROSBAG V2.0\n'
"""First bytes of every ROS 1 bag of format 2.0."""

OP_MESSAGE_DATA, OP_BAG_HEADER, OP_INDEX_DATA = 0x02, 0x03, 0x04
OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 0x05, 0x06, 0x07

MAX_HEADER_LENGTH = 1 << 24
"""Record headers longer than this [bytes] are taken as corruption (real ones are tiny)."""

ENTRY_SIZE = {OP_INDEX_DATA: 12, OP_CHUNK_INFO: 8}
"""Bytes per entry of the records whose data is ``count`` fixed-size entries."""

ReadAt = Callable[[int, int], bytes]


class Ros1FormatError(Exception):
    """The file is not a ROS 1 bag of format 2.0."""


class RecordReadError(Exception):
    """Reading stopped at a cut-off or corrupt record; ``offset`` is its byte position."""

    def __init__(self, reason: str, offset: int) -> None:
        """Store the reason and the byte offset of the failing record."""
        super().__init__(f'{reason} at byte {offset}')
        self.reason = reason
        self.offset = offset


@dataclass(frozen=True)
class Ros1Connection:
    """One connection record: topic, type (ROS 1 spelling), md5 and message definition."""

    conn_id: int
    topic: str
    msgtype: str
    md5sum: str
    definition: str


@dataclass
class _Record:
    """A parsed record: op code, header fields, data and where it started."""

    op: int
    header: dict[str, bytes]
    data: bytes
    offset: int
    next_offset: int
    complete: bool = True


def parse_header(raw: bytes) -> dict[str, bytes]:
    """Parse a record header (``<u32 len>name=value`` fields); raise ValueError if malformed."""
    fields: dict[str, bytes] = {}
    pos = 0
    while pos < len(raw):
        if pos + 4 > len(raw):
            raise ValueError('header field length cut off')
        (length,) = struct.unpack_from('<I', raw, pos)
        pos += 4
        if pos + length > len(raw):
            raise ValueError('header field exceeds its header')
        name, sep, value = raw[pos:pos + length].partition(b'=')
        if not sep:
            raise ValueError('header field without "="')
        fields[name.decode('ascii', 'replace')] = value
        pos += length
    return fields


def _uint32(header: dict[str, bytes], name: str) -> int:
    """Return a little-endian uint32 header field."""
    return struct.unpack('<I', header[name][:4])[0]


def _time_ns(value: bytes) -> int:
    """Return a ROS 1 time field (u32 sec, u32 nsec) in nanoseconds."""
    sec, nsec = struct.unpack('<II', value[:8])
    return sec * 1_000_000_000 + nsec


def _plausible_record(read_at: ReadAt, pos: int, end: int) -> bool:
    """Tell whether a record header with an ``op`` field starts at ``pos`` (or pos is the end)."""
    if pos == end:
        return True
    raw = read_at(pos, 4)
    if len(raw) < 4:
        return False
    (length,) = struct.unpack('<I', raw)
    if length > MAX_HEADER_LENGTH or pos + 4 + length > end:
        return False
    try:
        return 'op' in parse_header(read_at(pos + 4, length))
    except ValueError:
        return False


def _read_record(read_at: ReadAt, pos: int, end: int) -> _Record:
    """Read the record at ``pos``; raise :class:`RecordReadError` if it is cut off or bad."""
    raw = read_at(pos, 4)
    if len(raw) < 4:
        raise RecordReadError('record header length cut off', pos)
    (header_length,) = struct.unpack('<I', raw)
    if header_length > MAX_HEADER_LENGTH:
        raise RecordReadError(f'implausible header length {header_length}', pos)
    if pos + 8 + header_length > end:
        raise RecordReadError('record header cut off', pos)
    try:
        header = parse_header(read_at(pos + 4, header_length))
        op = header['op'][0]
    except (ValueError, KeyError, IndexError):
        raise RecordReadError('corrupt record header', pos) from None
    data_start = pos + 8 + header_length
    (data_length,) = struct.unpack('<I', read_at(pos + 4 + header_length, 4))
    if op in ENTRY_SIZE and 'count' in header:
        counted = _uint32(header, 'count') * ENTRY_SIZE[op]
        if (counted != data_length and not _plausible_record(read_at, data_start + data_length,
                                                             end)
                and _plausible_record(read_at, data_start + counted, end)):
            data_length = counted
    available = min(data_length, max(end - data_start, 0))
    data = read_at(data_start, available)
    return _Record(op, header, data, pos, data_start + data_length,
                   complete=len(data) == data_length)


def _walk(read_at: ReadAt, start: int, end: int) -> Iterator[_Record]:
    """Yield the records between ``start`` and ``end``; stop at the first damaged one.

    A cut-off chunk record is still yielded (its complete inner records are usable);
    any other cut-off record raises :class:`RecordReadError` instead.
    """
    pos = start
    while pos < end:
        record = _read_record(read_at, pos, end)
        if not record.complete and record.op != OP_CHUNK:
            raise RecordReadError('record data cut off', pos)
        yield record
        if not record.complete:
            raise RecordReadError('chunk cut off', pos)
        pos = record.next_offset


def _decompress(compression: bytes, data: bytes, offset: int) -> bytes:
    """Decompress a chunk; a cut-off stream yields the bytes it decodes to."""
    if compression == b'none':
        return data
    try:
        if compression == b'bz2':
            return bz2.BZ2Decompressor().decompress(data)
        if compression == b'lz4':
            return lz4.frame.LZ4FrameDecompressor().decompress(data)
    except (OSError, RuntimeError, EOFError, ValueError) as err:
        raise RecordReadError(f'undecodable {compression.decode()} chunk ({err})',
                              offset) from None
    raise RecordReadError(f'unsupported chunk compression {compression.decode()!r}', offset)


class Ros1RecordReader:
    """Reads connection and message records of a ROS 1 bag in file order."""

    def __init__(self, path: Path) -> None:
        """Open ``path``; raise :class:`Ros1FormatError` if it is not a ROS 1 v2.0 bag."""
        self.path = Path(path)
        self._file: BinaryIO = self.path.open('rb')
        if self._file.read(len(MAGIC)) != MAGIC:
            self._file.close()
            raise Ros1FormatError(f'{self.path} is not a ROS 1 bag (format 2.0)')
        self._size = self.path.stat().st_size

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def _read_at(self, pos: int, size: int) -> bytes:
        """Return up to ``size`` bytes of the file from ``pos``."""
        self._file.seek(pos)
        return self._file.read(size)

    def records(self) -> Iterator[tuple[_Record, bool]]:
        """Yield ``(record, in_chunk)`` for every record, chunk contents in place of chunks.

        Raises :class:`RecordReadError` after the last readable record when the file is
        cut off or corrupt.
        """
        for record in _walk(self._read_at, len(MAGIC), self._size):
            if record.op != OP_CHUNK:
                yield record, False
                continue
            body = _decompress(record.header.get('compression', b'none'), record.data,
                               record.offset)
            base = record.offset

            def read_chunk(pos: int, size: int, body: bytes = body) -> bytes:
                return body[pos:pos + size]

            try:
                for inner in _walk(read_chunk, 0, len(body)):
                    yield inner, True
            except RecordReadError as err:
                raise RecordReadError(f'{err.reason} inside the chunk', base) from None

    def connections(self) -> dict[int, Ros1Connection]:
        """Return every readable connection, by id (a damaged tail is ignored here)."""
        found: dict[int, Ros1Connection] = {}
        try:
            for record, _ in self.records():
                if record.op == OP_CONNECTION:
                    connection = self._connection(record)
                    found.setdefault(connection.conn_id, connection)
        except RecordReadError:
            pass
        return found

    @staticmethod
    def _connection(record: _Record) -> Ros1Connection:
        """Decode a connection record (its data is a header with type, md5 and definition)."""
        try:
            fields = parse_header(record.data)
        except ValueError:
            raise RecordReadError('corrupt connection record', record.offset) from None
        text = {k: v.decode('utf-8', 'replace') for k, v in fields.items()}
        topic = record.header.get('topic', fields.get('topic', b'')).decode('utf-8', 'replace')
        return Ros1Connection(_uint32(record.header, 'conn'), topic, text.get('type', ''),
                              text.get('md5sum', ''), text.get('message_definition', ''))

    def messages(self, conn_ids: set[int] | None = None) -> Iterator[tuple[int, int, bytes]]:
        """Yield ``(conn_id, record_time_ns, raw)`` of message records in file order.

        Raises :class:`RecordReadError` after the last complete message when the file is
        damaged.
        """
        for record, _ in self.records():
            if record.op != OP_MESSAGE_DATA:
                continue
            try:
                conn = _uint32(record.header, 'conn')
                stamp = _time_ns(record.header['time'])
            except (KeyError, struct.error):
                raise RecordReadError('corrupt message record', record.offset) from None
            if conn_ids is None or conn in conn_ids:
                yield conn, stamp, record.data

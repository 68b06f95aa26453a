"""Reading what is left of damaged ROS 2 bag files (MCAP and SQLite 3 storage).

rosbags opens an MCAP file from its footer and summary, and an SQLite bag through its
timestamp index; a recording cut short has neither, so rosbags refuses it outright.
These readers walk the data the way it was written instead:

- MCAP (https://mcap.dev/spec): records are ``<u8 op><u64 length><content>`` from the
  leading magic on; schema, channel and message records are read directly or from
  inside chunk records (decompressed: none, zstd, lz4). A chunk cut off by the end
  of the file still delivers its complete messages when its stream decodes.
- SQLite 3: SQLite itself reports a cut file as malformed (the b-tree interior pages
  it starts from may be lost even when most rows survived), so the rows are read from
  the table-leaf pages that are present (:mod:`laser_odom.io.sqlite_pages`) and
  delivered in rowid (= insertion) order up to the first missing one.

Both raise :class:`SalvageError` after the last message they could deliver.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import struct
from typing import BinaryIO, Iterator

import lz4.frame

from laser_odom.io.sqlite_pages import Cell, PageError, SqlitePages

try:  # Python >= 3.14 ships zstd; rosbags depends on the backport before that.
    from compression import zstd  # type: ignore[import-not-found]
except ImportError:  # pragma: no cover - depends on the interpreter
    from backports import zstd

MCAP_MAGIC = b'\x89MCAP0\r\n'
"""Leading (and trailing) magic of an MCAP file."""


OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_DATA_END = 0x03, 0x04, 0x05, 0x06, 0x0F


class SalvageError(Exception):
    """Reading stopped at damaged data; the message says where and why."""


@dataclass(frozen=True)
class RawChannel:
    """A topic of a ROS 2 storage file with its type and (optional) definition."""

    topic: str
    msgtype: str
    encoding: str = ''
    definition: str = ''


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    """Read an MCAP ``<u32 length><utf-8>`` string; return it and the next position."""
    (length,) = struct.unpack_from('<I', buf, pos)
    end = pos + 4 + length
    if end > len(buf):
        raise struct.error('string exceeds its record')
    return buf[pos + 4:end].decode('utf-8', 'replace'), end


def _decompress_mcap(compression: str, data: bytes, size: int) -> bytes:
    """Decompress an MCAP chunk; a cut-off stream gives the bytes it decodes to."""
    if compression == '':
        return data
    try:
        if compression == 'zstd':
            return zstd.ZstdDecompressor().decompress(data, max_length=size)
        if compression == 'lz4':
            return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)
    except (zstd.ZstdError, RuntimeError, EOFError, ValueError) as err:
        raise SalvageError(f'undecodable {compression} chunk ({err})') from None
    raise SalvageError(f'unsupported MCAP chunk compression {compression!r}')


class McapSalvageReader:
    """Walks the records of an MCAP file in order, without its summary section."""

    def __init__(self, path: Path) -> None:
        """Open ``path``; raise ValueError when it is not an MCAP file."""
        self.path = Path(path)
        self._file: BinaryIO = self.path.open('rb')
        if self._file.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            self._file.close()
            raise ValueError(f'{self.path} is not an MCAP file')
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.channels: dict[int, RawChannel] = {}

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def _records(self, buf: bytes, offset: int) -> Iterator[tuple[int, bytes]]:
        """Yield ``(op, content)`` of the complete records in ``buf``; raise at a cut one."""
        pos = 0
        while pos < len(buf):
            if pos + 9 > len(buf):
                raise SalvageError(f'MCAP record cut off at byte {offset + pos}')
            op = buf[pos]
            (length,) = struct.unpack_from('<Q', buf, pos + 1)
            if pos + 9 + length > len(buf):
                raise SalvageError(f'MCAP record cut off at byte {offset + pos}')
            yield op, buf[pos + 9:pos + 9 + length]
            pos += 9 + length

    def _top_level(self) -> Iterator[tuple[int, bytes, int, bool]]:
        """Yield ``(op, content, offset, complete)`` of top-level records from the file."""
        f = self._file
        f.seek(len(MCAP_MAGIC))
        while True:
            offset = f.tell()
            head = f.read(9)
            if not head:
                return
            if len(head) < 9:
                raise SalvageError(f'MCAP record cut off at byte {offset}')
            op = head[0]
            (length,) = struct.unpack_from('<Q', head, 1)
            content = f.read(length)
            complete = len(content) == length
            if not complete and op != OP_CHUNK:
                raise SalvageError(f'MCAP record cut off at byte {offset}')
            yield op, content, offset, complete
            if not complete:
                raise SalvageError(f'MCAP chunk cut off at byte {offset}')
            if op == OP_DATA_END:
                return

    def records(self) -> Iterator[tuple[int, bytes]]:
        """Yield ``(op, content)`` of every data record, chunk contents in place of chunks."""
        for op, content, offset, _ in self._top_level():
            if op != OP_CHUNK:
                yield op, content
                continue
            try:
                _, _, size, _ = struct.unpack_from('<QQQI', content, 0)
                compression, pos = _string(content, 28)
                (records_length,) = struct.unpack_from('<Q', content, pos)
            except struct.error:
                raise SalvageError(f'MCAP chunk header cut off at byte {offset}') from None
            body = _decompress_mcap(compression, content[pos + 8:pos + 8 + records_length], size)
            yield from self._records(body, offset)

    def messages(self, topics: set[str]) -> Iterator[tuple[RawChannel, int, bytes]]:
        """Yield ``(channel, log_time_ns, cdr_bytes)`` of the wanted topics, in file order."""
        for op, content in self.records():
            try:
                if op == OP_SCHEMA:
                    (sid,) = struct.unpack_from('<H', content, 0)
                    name, pos = _string(content, 2)
                    encoding, pos = _string(content, pos)
                    (size,) = struct.unpack_from('<I', content, pos)
                    text = content[pos + 4:pos + 4 + size].decode('utf-8', 'replace')
                    self.schemas[sid] = (name, encoding, text)
                elif op == OP_CHANNEL:
                    cid, sid = struct.unpack_from('<HH', content, 0)
                    topic, _ = _string(content, 4)
                    name, encoding, text = self.schemas.get(sid, ('', '', ''))
                    self.channels[cid] = RawChannel(topic, name, encoding, text)
                elif op == OP_MESSAGE:
                    cid, _, log_time, _ = struct.unpack_from('<HIQQ', content, 0)
                    channel = self.channels.get(cid)
                    if channel is not None and channel.topic in topics:
                        yield channel, log_time, content[22:]
            except struct.error:
                raise SalvageError(f'corrupt MCAP record (op {op:#04x})') from None

    def read_channels(self) -> list[RawChannel]:
        """Return the channels declared in the readable part of the file."""
        try:
            for _ in self.messages(set()):
                pass
        except SalvageError:
            pass
        return list(self.channels.values())


def _is_message_row(serials: list[int]) -> bool:
    """Tell whether a record looks like a rosbag2 ``messages`` row (id, topic_id, stamp, data).

    ``id`` is the rowid alias (stored as NULL); integers are serial types 1-6, or 8 and
    9 for the constants 0 and 1; ``data`` is a BLOB (even serial type >= 12).
    """
    integer = (1, 2, 3, 4, 5, 6, 8, 9)
    return (len(serials) == 4 and serials[0] == 0 and serials[1] in integer
            and serials[2] in integer and serials[3] >= 12 and serials[3] % 2 == 0)


def _is_topic_row(serials: list[int]) -> bool:
    """Tell whether a record may be a ``topics`` row (id, name, type, format, ...)."""
    return (len(serials) >= 4 and serials[0] == 0
            and all(s >= 13 and s % 2 == 1 for s in serials[1:4]))


class SqliteSalvageReader:
    """Reads the messages of a (possibly cut-off) rosbag2 SQLite 3 file from its pages.

    Rows come in rowid (= insertion) order up to the first missing one; types are
    taken from the standard ROS 2 definitions (the ``message_definitions`` table is
    not consulted).
    """

    def __init__(self, path: Path) -> None:
        """Index the message and topic rows present; ValueError if there are no topics."""
        self.path = Path(path)
        self._pages = SqlitePages(self.path)
        self.channels: dict[int, RawChannel] = {}
        cells: dict[int, Cell] = {}
        for cell in self._pages.leaf_cells():
            try:
                serials = self._pages.serial_types(cell)
                if _is_message_row(serials):
                    cells.setdefault(cell.rowid, cell)
                elif _is_topic_row(serials):
                    values = self._pages.record(cell)
                    if str(values[1]).startswith('/') and values[3] == 'cdr':
                        self.channels[cell.rowid] = RawChannel(str(values[1]), str(values[2]))
            except PageError:
                continue
        if not self.channels:
            self.close()
            raise ValueError(f'{self.path}: no rosbag2 topics table readable')
        self._cells = [cells[k] for k in sorted(cells)]

    def close(self) -> None:
        """Close the file."""
        self._pages.close()

    def messages(self, topics: set[str]) -> Iterator[tuple[RawChannel, int, bytes]]:
        """Yield ``(channel, timestamp_ns, cdr_bytes)`` of the wanted topics in rowid order.

        Raises :class:`SalvageError` at the first missing row, or after the last one.
        """
        ids = {tid for tid, ch in self.channels.items() if ch.topic in topics}
        previous = 0
        for cell in self._cells:
            if cell.rowid != previous + 1:
                raise SalvageError(f'message rows from id {previous + 1} on are missing')
            try:
                _, tid, stamp, data = self._pages.record(cell)
            except (PageError, ValueError) as err:
                raise SalvageError(f'message id {cell.rowid} is damaged ({err})') from None
            previous = cell.rowid
            if tid in ids:
                yield self.channels[tid], int(stamp), bytes(data)
        raise SalvageError(f'database cut off after message id {previous}')

"""Rows of a damaged SQLite 3 file, read straight from its pages.

A cut-off database cannot be queried: SQLite walks each table's b-tree from the root,
and the interior pages it needs may lie in the lost part of the file even when most
leaf pages survived. The rows themselves sit in table-leaf pages, so this module
reads every page that is present and decodes the cells of the table-leaf pages,
following overflow chains (SQLite file format, https://www.sqlite.org/fileformat.html:
sec. 1.6 b-tree pages, 1.6 cell payload and overflow formulas, 2.1 record format).
Pages that are not table leaves (interior, index, free pages) are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import struct
from typing import BinaryIO, Iterator

SQLITE_MAGIC = b'SQLite format 3\x00'
TABLE_LEAF = 0x0D


class PageError(Exception):
    """A page or cell cannot be decoded (outside the file, or malformed)."""


def varint(buf: bytes, pos: int) -> tuple[int, int]:
    """Decode a variable-length integer: 1-9 bytes, big-endian, 7 bits each but the 9th."""
    value = 0
    for i in range(9):
        if pos + i >= len(buf):
            raise PageError('varint beyond the page')
        byte = buf[pos + i]
        if i == 8:
            return (value << 8) | byte, pos + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    raise PageError('unreachable')  # pragma: no cover


def _serial_size(serial: int) -> int:
    """Return the byte size of a value of the given serial type (fileformat sec. 2.1)."""
    if serial >= 12:
        return (serial - 12) // 2 if serial % 2 == 0 else (serial - 13) // 2
    return (0, 1, 2, 3, 4, 6, 8, 8, 0, 0, 0, 0)[serial]


def decode_record(payload: bytes) -> list[object]:
    """Decode a record into Python values (None, int, float, bytes; text as str)."""
    header_size, pos = varint(payload, 0)
    serials = []
    while pos < header_size:
        serial, pos = varint(payload, pos)
        serials.append(serial)
    values: list[object] = []
    pos = header_size
    for serial in serials:
        size = _serial_size(serial)
        raw = payload[pos:pos + size]
        if len(raw) != size:
            raise PageError('record shorter than its header says')
        if serial == 0:
            values.append(None)
        elif serial <= 6:
            values.append(int.from_bytes(raw, 'big', signed=True))
        elif serial == 7:
            values.append(struct.unpack('>d', raw)[0])
        elif serial in (8, 9):
            values.append(serial - 8)
        elif serial % 2 == 0:
            values.append(raw)
        else:
            values.append(raw.decode('utf-8', 'replace'))
        pos += size
    return values


@dataclass(frozen=True)
class Cell:
    """Where one table row lives: its rowid, page, and offset in the page."""

    rowid: int
    page: int
    offset: int


class SqlitePages:
    """Page-level access to an SQLite 3 file, tolerant of a missing tail."""

    def __init__(self, path: Path) -> None:
        """Open ``path``; raise ValueError if it is not an SQLite 3 database."""
        self.path = Path(path)
        self._file: BinaryIO = self.path.open('rb')
        head = self._file.read(100)
        if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
            self._file.close()
            raise ValueError(f'{self.path} is not an SQLite 3 database')
        size = struct.unpack_from('>H', head, 16)[0]
        self.page_size = 65536 if size == 1 else size
        self.usable = self.page_size - head[20]
        self.pages = self.path.stat().st_size // self.page_size

    def close(self) -> None:
        """Close the file."""
        self._file.close()

    def page(self, number: int) -> bytes:
        """Return page ``number`` (1-based); PageError if it lies beyond the file's end."""
        if not 1 <= number <= self.pages:
            raise PageError(f'page {number} is missing')
        self._file.seek((number - 1) * self.page_size)
        return self._file.read(self.page_size)

    def leaf_cells(self) -> Iterator[Cell]:
        """Yield every cell of every table-leaf page present, in page order."""
        for number in range(1, self.pages + 1):
            page = self.page(number)
            base = 100 if number == 1 else 0
            if page[base] != TABLE_LEAF:
                continue
            (count,) = struct.unpack_from('>H', page, base + 3)
            if base + 8 + 2 * count > len(page):
                continue
            for k in range(count):
                (offset,) = struct.unpack_from('>H', page, base + 8 + 2 * k)
                try:
                    _, pos = varint(page, offset)
                    rowid, _ = varint(page, pos)
                except PageError:
                    continue
                yield Cell(rowid, number, offset)

    def payload(self, cell: Cell) -> bytes:
        """Return a cell's payload, following its overflow chain (fileformat sec. 1.6).

        Raises PageError when an overflow page is missing.
        """
        page = self.page(cell.page)
        size, pos = varint(page, cell.offset)
        _, pos = varint(page, pos)
        u = self.usable
        max_local = u - 35
        if size <= max_local:
            local = size
        else:
            min_local = ((u - 12) * 32 // 255) - 23
            local = min_local + (size - min_local) % (u - 4)
            local = local if local <= max_local else min_local
        parts = [page[pos:pos + local]]
        have = local
        if local < size:
            (next_page,) = struct.unpack_from('>I', page, pos + local)
            while have < size:
                if next_page == 0:
                    raise PageError('overflow chain ends early')
                overflow = self.page(next_page)
                (next_page,) = struct.unpack_from('>I', overflow, 0)
                chunk = overflow[4:min(u, 4 + size - have)]
                parts.append(chunk)
                have += len(chunk)
        return b''.join(parts)

    def serial_types(self, cell: Cell) -> list[int]:
        """Return the column serial types of a cell's record (its header, in the local part)."""
        page = self.page(cell.page)
        _, pos = varint(page, cell.offset)
        _, pos = varint(page, pos)
        header_size, at = varint(page, pos)
        serials = []
        while at < pos + header_size:
            serial, at = varint(page, at)
            serials.append(serial)
        return serials

    def record(self, cell: Cell) -> list[object]:
        """Return the decoded record of a cell; PageError when part of it is missing."""
        return decode_record(self.payload(cell))

"""Message sources behind :class:`laser_odom.io.bag_reader.BagReader`.

Each source lists a bag's topics (name -> ROS 2 style type, ``pkg/msg/Type``) and
yields deserialised messages of chosen topics. ``RosbagsSource`` is the normal path
(rosbags' ``AnyReader``: ROS 1 bags, ROS 2 directories, single .db3/.mcap files); the
other two read bags that rosbags refuses - ROS 1 bags with a missing or non-standard
index, and cut-off ROS 2 storage files - record by record. Damage met while reading
raises :class:`SourceReadError` after every message before it has been delivered.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Collection, Iterator

from rosbags.highlevel import AnyReader
from rosbags.typesys import (
    get_types_from_idl, get_types_from_msg, get_typestore, Stores, TypesysError)
from rosbags.typesys.msg import normalize_msgtype

from laser_odom.io.ros1_records import RecordReadError, Ros1RecordReader
from laser_odom.io.ros2_salvage import (
    McapSalvageReader, RawChannel, SalvageError, SqliteSalvageReader)

Message = tuple[str, int, Any]
"""``(topic, log_time_ns, message)`` as yielded by every source."""


class SourceReadError(Exception):
    """Reading stopped at damaged data; the text says where and why."""


def _register_definition(msgtype: str, encoding: str, text: str, default: Any) -> Any | None:
    """Return a typestore holding ``msgtype`` built from its bag definition, or None.

    ROS 1 connections and ROS 2 ``ros2msg`` schemas carry ``.msg`` text (dependencies
    appended after ``====`` separators); ``ros2idl`` schemas carry IDL sections.
    Dependencies the text leaves out (old ROS 1 bags define ``roslib/Header`` where
    the fields say ``Header``) come from the ``default`` store.
    """
    if not text.strip():
        return None
    try:
        if encoding == 'ros2idl':
            types: dict[str, Any] = {}
            sep = '=' * 80 + '\n'
            sections = text.split(sep)[1:] if text.startswith(f'{sep}IDL: ') else [text]
            for section in sections:
                types.update(get_types_from_idl(section.split('\n', 1)[-1]
                                                if section.startswith('IDL: ') else section))
        else:
            types = get_types_from_msg(text, msgtype)
        store = get_typestore(Stores.EMPTY)
        store.register({**default.fielddefs, **types})
    except (TypesysError, ValueError, KeyError):
        return None
    return store if msgtype in store.types else None


class _TypeResolver:
    """Picks the typestore for each message type: the bag's definition, else a default."""

    def __init__(self, default: Any) -> None:
        """Use ``default`` for types the bag does not define (or defines unreadably)."""
        self.default = default
        self._stores: dict[tuple[str, str], Any] = {}

    def store(self, msgtype: str, encoding: str, definition: str) -> Any:
        """Return a typestore able to deserialise ``msgtype``."""
        key = (msgtype, definition)
        if key not in self._stores:
            own = _register_definition(msgtype, encoding, definition, self.default)
            self._stores[key] = own if own is not None else self.default
        return self._stores[key]


class RosbagsSource:
    """Messages of a sound bag through rosbags' ``AnyReader``."""

    def __init__(self, path: Path) -> None:
        """Open ``path`` (a .bag file, a ROS 2 directory or a .db3/.mcap file)."""
        ros1 = path.suffix == '.bag'
        default = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_JAZZY)
        self._reader = AnyReader([path], default_typestore=default)
        self._reader.open()
        self.topics = {name: info.msgtype or '' for name, info in self._reader.topics.items()}
        self.counts: dict[str, int] = {
            name: info.msgcount for name, info in self._reader.topics.items()}
        """Messages per topic, as the bag's index says (the record readers have none)."""

    def close(self) -> None:
        """Close the reader."""
        self._reader.close()

    def messages(self, topics: Collection[str]) -> Iterator[Message]:
        """Yield the messages of ``topics`` in time order."""
        reader = self._reader
        connections = [c for c in reader.connections if c.topic in topics]
        if not connections:
            return
        stream = reader.messages(connections=connections)
        while True:
            try:
                connection, stamp, raw = next(stream)
                message = reader.deserialize(raw, connection.msgtype)
            except StopIteration:
                return
            except Exception as err:  # noqa: B902 - any failure here is bag damage
                raise SourceReadError(f'{type(err).__name__}: {err}') from None
            yield connection.topic, stamp, message


class Ros1RecordSource:
    """Messages of a ROS 1 bag read record by record (no index needed)."""

    def __init__(self, path: Path) -> None:
        """Open ``path``; ValueError if it is not a ROS 1 bag."""
        self._reader = Ros1RecordReader(path)
        self._connections = self._reader.connections()
        self._types = _TypeResolver(get_typestore(Stores.ROS1_NOETIC))
        self.topics = {c.topic: normalize_msgtype(c.msgtype)
                       for c in self._connections.values()}
        self.counts: dict[str, int] = {}

    def close(self) -> None:
        """Close the file."""
        self._reader.close()

    def messages(self, topics: Collection[str]) -> Iterator[Message]:
        """Yield the messages of ``topics`` in file order."""
        wanted = {cid for cid, c in self._connections.items() if c.topic in topics}
        if not wanted:
            return
        try:
            for cid, stamp, raw in self._reader.messages(wanted):
                connection = self._connections[cid]
                msgtype = normalize_msgtype(connection.msgtype)
                store = self._types.store(msgtype, 'ros1msg', connection.definition)
                yield connection.topic, stamp, store.deserialize_ros1(raw, msgtype)
        except RecordReadError as err:
            raise SourceReadError(str(err)) from None
        except Exception as err:  # noqa: B902 - a message that does not decode is damage
            raise SourceReadError(f'undecodable message ({type(err).__name__}: {err})') from None


class Ros2SalvageSource:
    """Messages of (possibly cut-off) ROS 2 storage files, read without their index."""

    def __init__(self, files: list[Path]) -> None:
        """Open every storage file (.mcap or .db3, by content); ValueError if one is neither."""
        self._readers: list[McapSalvageReader | SqliteSalvageReader] = []
        try:
            for path in files:
                with path.open('rb') as f:
                    magic = f.read(8)
                if magic.startswith(b'\x89MCAP'):
                    self._readers.append(McapSalvageReader(path))
                else:
                    self._readers.append(SqliteSalvageReader(path))
        except (ValueError, OSError):
            self.close()
            raise
        self._types = _TypeResolver(get_typestore(Stores.ROS2_JAZZY))
        self.topics: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        for reader in self._readers:
            channels = (reader.read_channels() if isinstance(reader, McapSalvageReader)
                        else reader.channels.values())
            for channel in channels:
                self.topics.setdefault(channel.topic, channel.msgtype)

    def close(self) -> None:
        """Close every storage file."""
        for reader in self._readers:
            reader.close()

    def _decode(self, channel: RawChannel, raw: bytes) -> Any:
        """Deserialise one CDR message."""
        store = self._types.store(channel.msgtype, channel.encoding, channel.definition)
        return store.deserialize_cdr(raw, channel.msgtype)

    def messages(self, topics: Collection[str]) -> Iterator[Message]:
        """Yield the messages of ``topics``, file after file, each in written order."""
        wanted = set(topics)
        for reader in self._readers:
            try:
                for channel, stamp, raw in reader.messages(wanted):
                    yield channel.topic, stamp, self._decode(channel, raw)
            except SalvageError as err:
                raise SourceReadError(f'{reader.path.name}: {err}') from None
            except Exception as err:  # noqa: B902 - a message that does not decode is damage
                raise SourceReadError(
                    f'{reader.path.name}: undecodable message ({type(err).__name__})') from None

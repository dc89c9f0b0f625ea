"""Salvage: a bag rosbags cannot open (a ROS 1 bag or an MCAP file cut short, so with no
index and no summary) read record by record from its start until its damage. Every message
whole before the damage is kept; the reader says where it stopped.
"""

from __future__ import annotations

from pathlib import Path

from swarmslam.formats.bags.common import TF_MESSAGE_ROS1, TF_TYPE, BagError, rosbags


def salvaged(path: Path, records):
    """Topics and messages of a damaged bag, read in one pass from its start (the messages
    are kept in memory: a cut file has no index to come back through)."""
    topics, kept, stopped = {}, [], None
    try:
        for topic, msgtype, message in records(path):
            topics.setdefault(topic, msgtype)
            kept.append((topic, msgtype, message))
    except Exception as exc:
        stopped = exc

    def messages(wanted):
        for item in kept:
            if item[0] in wanted:
                yield item
        if stopped is not None:
            raise stopped

    messages.salvaged = True
    return topics, messages


def _ros1_type(name: str) -> str:
    package, _, kind = name.partition("/")
    return f"{package}/msg/{kind}"


def ros1_records(path: Path):
    """(topic, type, message) of a ROS 1 bag, record by record from its start (format 2.0)."""
    import bz2
    import struct

    rb = rosbags()
    store = rb.typesys.get_typestore(rb.typesys.Stores.ROS1_NOETIC)
    store.register(rb.typesys.get_types_from_msg(TF_MESSAGE_ROS1, TF_TYPE))
    connections = {}

    def fields(header: bytes) -> dict:
        out, i = {}, 0
        while i < len(header):
            (size,) = struct.unpack_from("<I", header, i)
            name, _, value = header[i + 4:i + 4 + size].partition(b"=")
            out[name.decode()] = value
            i += 4 + size
        return out

    def records(data: bytes):
        """(header, body, whole) of each record; the last may be cut short (not whole)."""
        i = 0
        while i + 4 <= len(data):
            (size,) = struct.unpack_from("<I", data, i)
            if i + 8 + size > len(data):
                raise BagError("a record cut short")
            header = data[i + 4:i + 4 + size]
            (length,) = struct.unpack_from("<I", data, i + 4 + size)
            body = data[i + 8 + size:i + 8 + size + length]
            yield fields(header), body, len(body) == length
            i += 8 + size + length

    def messages(data: bytes):
        for header, body, whole in records(data):
            op = header.get("op", b"\0")[0]
            if not whole and not (op == 0x05 and header["compression"] == b"none"):
                raise BagError("a record cut short")
            if op == 0x07:  # connection
                info = fields(body)
                connections[struct.unpack("<I", header["conn"])[0]] = (
                    header["topic"].decode(), _ros1_type(info["type"].decode()))
            elif op == 0x02:  # message data
                topic, msgtype = connections[struct.unpack("<I", header["conn"])[0]]
                if msgtype in store.types:
                    yield topic, msgtype, store.deserialize_ros1(body, msgtype)
            elif op == 0x05:  # a chunk: its records within
                kind = header["compression"].decode()
                inner = body if kind == "none" else bz2.decompress(body) if kind == "bz2" \
                    else _lz4(body)
                yield from messages(inner)  # (a chunk cut short: the records it still holds)
                if not whole:
                    raise BagError("a chunk cut short")

    raw = path.read_bytes()
    if not raw.startswith(b"#ROSBAG V2.0\n"):
        raise BagError(f"{path}: not a ROS 1 bag (format 2.0)")
    yield from messages(raw[len(b"#ROSBAG V2.0\n"):])


def _lz4(body: bytes) -> bytes:
    import lz4.frame

    return lz4.frame.decompress(body)


def _zstd(body: bytes) -> bytes:
    try:  # Python 3.14's own, else the backport rosbags installs
        from compression import zstd
    except ImportError:
        from backports import zstd
    return zstd.decompress(body)


def mcap_records(path: Path):
    """(topic, type, message) of an MCAP file, record by record from its start; the records
    an uncompressed chunk cut short still holds are read too (MCAP's record layout:
    opcode u8, length u64, body)."""
    import struct

    rb = rosbags()
    store = rb.typesys.get_typestore(rb.typesys.Stores.ROS2_HUMBLE)
    schemas, channels = {}, {}

    def text(body: bytes, i: int):
        (size,) = struct.unpack_from("<I", body, i)
        return body[i + 4:i + 4 + size].decode(), i + 4 + size

    def records(data: bytes):
        i = 0
        while i + 9 <= len(data):
            opcode, length = struct.unpack_from("<BQ", data, i)
            body = data[i + 9:i + 9 + length]
            yield opcode, body, len(body) == length
            i += 9 + length

    def messages(data: bytes):
        for opcode, body, whole in records(data):
            if opcode == 0x06:  # a chunk: its records within
                compression, at = text(body, 28)  # after start, end, size (u64), crc (u32)
                if compression not in ("", "zstd", "lz4") or (compression and not whole):
                    raise BagError(f"a chunk cut short or compressed as {compression!r}")
                inner = body[at + 8:]
                if compression == "zstd":
                    inner = _zstd(inner)
                elif compression == "lz4":
                    inner = _lz4(inner)
                yield from messages(inner)
                if not whole:
                    raise BagError("a chunk cut short")
            elif not whole:
                raise BagError("a record cut short")
            elif opcode == 0x03:  # schema
                (sid,) = struct.unpack_from("<H", body)
                schemas[sid], _ = text(body, 2)
            elif opcode == 0x04:  # channel
                cid, sid = struct.unpack_from("<HH", body)
                topic, _ = text(body, 4)
                channels[cid] = (topic, schemas.get(sid, ""))
            elif opcode == 0x05:  # message
                (cid,) = struct.unpack_from("<H", body)
                topic, msgtype = channels[cid]
                if msgtype in store.types:
                    yield topic, msgtype, store.deserialize_cdr(body[22:], msgtype)

    raw = path.read_bytes()
    magic = b"\x89MCAP0\r\n"
    if not raw.startswith(magic):
        raise BagError(f"{path}: not an MCAP file")
    yield from messages(raw[len(magic):])

"""XCDR1 (plain CDR, little endian) encoder and decoder for ROS 2 messages.

This is the codec twinslam's node runtime puts on the wire. It is compiled once per message type
from the field definitions in :mod:`msg_schemas.registry` into a list of small closures, so a
message costs one Python call per field, and numeric arrays (images, descriptors, id lists) cost
one ``memcpy``: that is the fast path DESIGN.md §6 asks for (Cyclone's generic Python path spends
~35 ms per MB on ``uint8[]``).

Decoding is defensive because the bytes come from the network: every length is checked against
the bytes that remain *before* anything is allocated, so a sequence length of 4 G in a 100-byte
payload is a :class:`CdrError`, never a 4 GB allocation.

Alignment follows XCDR1: a primitive of size n is aligned to n bytes, counted from the end of the
4-byte encapsulation header.
"""

from __future__ import annotations

import functools
import struct
from collections.abc import Callable
from typing import Any

import numpy as np

from msg_schemas.registry import PRIMITIVE_DTYPES, message_class, typestore

#: Encapsulation header for CDR little endian (what ROS 2 writes: ``00 01 00 00``).
CDR_LE_HEADER = b"\x00\x01\x00\x00"
HEADER_SIZE = 4

_STRUCT: dict[str, struct.Struct] = {
    "bool": struct.Struct("<?"),
    "byte": struct.Struct("<B"),
    "char": struct.Struct("<B"),
    "int8": struct.Struct("<b"),
    "uint8": struct.Struct("<B"),
    "int16": struct.Struct("<h"),
    "uint16": struct.Struct("<H"),
    "int32": struct.Struct("<i"),
    "uint32": struct.Struct("<I"),
    "int64": struct.Struct("<q"),
    "uint64": struct.Struct("<Q"),
    "float32": struct.Struct("<f"),
    "float64": struct.Struct("<d"),
}
_U32 = _STRUCT["uint32"]


class CdrError(ValueError):
    """Raised for bytes that are not a valid XCDR1 encoding of the expected message type."""


# Writer and reader state are a bytearray and an integer position; both align relative to the
# start of the payload (after the encapsulation header).


def _pad(out: bytearray, align: int) -> None:
    rem = (len(out) - HEADER_SIZE) % align
    if rem:
        out += b"\x00" * (align - rem)


def _aligned(pos: int, align: int) -> int:
    rem = (pos - HEADER_SIZE) % align
    return pos + (align - rem) if rem else pos


Encoder = Callable[[bytearray, Any], None]
Decoder = Callable[[memoryview, int], tuple[Any, int]]


def _need(buf: memoryview, pos: int, size: int, what: str) -> None:
    if size < 0 or pos + size > len(buf):
        raise CdrError(f"truncated payload: {what} needs {size} bytes at offset {pos}, "
                       f"{max(len(buf) - pos, 0)} remain")


# ---------------------------------------------------------------------------------------------
# Primitives and strings


def _primitive_codec(base: str) -> tuple[Encoder, Decoder]:
    st = _STRUCT[base]
    size = st.size
    pack, unpack = st.pack, st.unpack_from

    def enc(out: bytearray, value: Any) -> None:
        _pad(out, size)
        try:
            out += pack(value)
        except struct.error as exc:
            raise CdrError(f"{base} field cannot hold {value!r}: {exc}") from None

    def dec(buf: memoryview, pos: int) -> tuple[Any, int]:
        pos = _aligned(pos, size)
        _need(buf, pos, size, base)
        return unpack(buf, pos)[0], pos + size

    return enc, dec


def _string_codec(bound: int) -> tuple[Encoder, Decoder]:
    def enc(out: bytearray, value: str) -> None:
        data = value.encode("utf-8")
        if bound and len(data) > bound:
            raise CdrError(f"string of {len(data)} bytes exceeds its bound {bound}")
        _pad(out, 4)
        out += _U32.pack(len(data) + 1)
        out += data
        out += b"\x00"

    def dec(buf: memoryview, pos: int) -> tuple[str, int]:
        pos = _aligned(pos, 4)
        _need(buf, pos, 4, "string length")
        (n,) = _U32.unpack_from(buf, pos)
        pos += 4
        _need(buf, pos, n, "string")
        if n == 0:  # some writers send an empty string as length 0
            return "", pos
        if bound and n - 1 > bound:
            raise CdrError(f"string of {n - 1} bytes exceeds its bound {bound}")
        if buf[pos + n - 1] != 0:
            raise CdrError(f"string at offset {pos} is not NUL-terminated")
        try:
            text = bytes(buf[pos:pos + n - 1]).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise CdrError(f"string at offset {pos} is not UTF-8: {exc}") from None
        return text, pos + n

    return enc, dec


# ---------------------------------------------------------------------------------------------
# Numeric arrays and sequences: the fast path


def _numeric_array_codec(base: str, length: int | None, bound: int) -> tuple[Encoder, Decoder]:
    """Codec for ``T[N]`` (length given) or ``T[]``/``T[<=B]`` (length None) of a numeric T."""
    dtype = np.dtype(PRIMITIVE_DTYPES[base]).newbyteorder("<")
    itemsize = dtype.itemsize
    what = f"{base}[{length if length is not None else ''}]"

    def enc(out: bytearray, value: Any) -> None:
        arr = np.ascontiguousarray(value, dtype=dtype)
        if arr.ndim != 1:
            arr = arr.reshape(-1)
        n = arr.shape[0]
        if length is not None:
            if n != length:
                raise CdrError(f"{what} field got {n} elements")
        else:
            if bound and n > bound:
                raise CdrError(f"{what} sequence of {n} exceeds its bound {bound}")
            _pad(out, 4)
            out += _U32.pack(n)
        if n:
            _pad(out, itemsize)
            out += arr.data.cast("B")

    def dec(buf: memoryview, pos: int) -> tuple[np.ndarray, int]:
        if length is None:
            pos = _aligned(pos, 4)
            _need(buf, pos, 4, f"{what} length")
            (n,) = _U32.unpack_from(buf, pos)
            pos += 4
            if bound and n > bound:
                raise CdrError(f"{what} sequence of {n} exceeds its bound {bound}")
        else:
            n = length
        if n == 0:
            return np.zeros(0, dtype=dtype), pos
        pos = _aligned(pos, itemsize)
        _need(buf, pos, n * itemsize, what)
        arr = np.frombuffer(buf, dtype=dtype, count=n, offset=pos)
        if base == "bool" and np.any(buf[pos:pos + n].cast("B").tobytes().strip(b"\x00\x01")):
            raise CdrError(f"{what} holds a byte that is neither 0 nor 1")
        return arr, pos + n * itemsize

    return enc, dec


def _generic_array_codec(elem: tuple[Encoder, Decoder], min_size: int, length: int | None,
                         bound: int, what: str) -> tuple[Encoder, Decoder]:
    """Codec for arrays/sequences of strings or messages (one call per element)."""
    enc_elem, dec_elem = elem

    def enc(out: bytearray, value: Any) -> None:
        n = len(value)
        if length is not None:
            if n != length:
                raise CdrError(f"{what} field got {n} elements")
        else:
            if bound and n > bound:
                raise CdrError(f"{what} sequence of {n} exceeds its bound {bound}")
            _pad(out, 4)
            out += _U32.pack(n)
        for item in value:
            enc_elem(out, item)

    def dec(buf: memoryview, pos: int) -> tuple[list[Any], int]:
        if length is None:
            pos = _aligned(pos, 4)
            _need(buf, pos, 4, f"{what} length")
            (n,) = _U32.unpack_from(buf, pos)
            pos += 4
            if bound and n > bound:
                raise CdrError(f"{what} sequence of {n} exceeds its bound {bound}")
        else:
            n = length
        # Every element needs at least min_size bytes: refuse absurd counts before looping.
        _need(buf, pos, n * min_size, what)
        items = []
        for _ in range(n):
            item, pos = dec_elem(buf, pos)
            items.append(item)
        return items, pos

    return enc, dec


# ---------------------------------------------------------------------------------------------
# Messages


def _min_size(node: tuple[Any, Any]) -> int:
    """A lower bound of the encoded size of a field, used to reject absurd element counts."""
    kind, detail = int(node[0]), node[1]
    if kind == 1:
        return 4 if detail[0] == "string" else _STRUCT[detail[0]].size
    if kind == 2:
        _consts, defs = typestore().fielddefs[detail]
        return sum(_min_size(sub) for _, sub in defs)
    if kind == 3:
        return detail[1] * _min_size(detail[0])
    return 4


def _field_codec(node: tuple[Any, Any], what: str) -> tuple[Encoder, Decoder]:
    kind, detail = int(node[0]), node[1]
    if kind == 1:
        base, bound = detail
        return _string_codec(bound) if base == "string" else _primitive_codec(base)
    if kind == 2:
        codec = compiled(detail)
        return codec.encode_into, codec.decode_from
    sub, count = detail
    length, bound = (count, 0) if kind == 3 else (None, count)
    if int(sub[0]) == 1 and sub[1][0] in PRIMITIVE_DTYPES:
        return _numeric_array_codec(sub[1][0], length, bound)
    return _generic_array_codec(_field_codec(sub, what), _min_size(sub), length, bound, what)


class MessageCodec:
    """Encoder/decoder of one message type, built from its field definitions."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.cls = message_class(name)
        _consts, defs = typestore().fielddefs[name]
        self._fields: list[tuple[str, Encoder, Decoder]] = []
        self._field_names = [fname for fname, _ in defs]
        self._defs = defs

    def _build(self) -> None:
        # Deferred so that recursive lookups through compiled() see this codec in the cache.
        self._fields = [(fname, *_field_codec(node, f"{self.name}.{fname}"))
                        for fname, node in self._defs]
        if not self._fields:  # an empty ROS message still carries one uint8 member
            enc, dec = _primitive_codec("uint8")
            self._fields = [("structure_needs_at_least_one_member", enc, dec)]

    def encode_into(self, out: bytearray, msg: Any) -> None:
        for fname, enc, _dec in self._fields:
            try:
                value = getattr(msg, fname) if fname != "structure_needs_at_least_one_member" else 0
            except AttributeError:
                raise CdrError(f"{type(msg).__name__} lacks field {fname!r} "
                               f"of {self.name}") from None
            enc(out, value)

    def decode_from(self, buf: memoryview, pos: int) -> tuple[Any, int]:
        values = {}
        for fname, _enc, dec in self._fields:
            values[fname], pos = dec(buf, pos)
        values.pop("structure_needs_at_least_one_member", None)
        return self.cls(**values), pos

    def serialize(self, msg: Any) -> bytes:
        """Encapsulation header + XCDR1 little-endian body, exactly as ROS 2 writes it."""
        out = bytearray(CDR_LE_HEADER)
        self.encode_into(out, msg)
        return bytes(out)

    def deserialize(self, data: bytes | bytearray | memoryview) -> Any:
        """Decode header + body; trailing alignment padding is allowed, anything else is not."""
        buf = memoryview(data).cast("B")
        if len(buf) < HEADER_SIZE:
            raise CdrError(f"{len(buf)}-byte payload has no encapsulation header")
        if buf[0] != 0 or buf[1] not in (0, 1):
            raise CdrError(f"unsupported encapsulation {bytes(buf[:2]).hex()} "
                           "(expected plain CDR, 0000 or 0001)")
        if buf[1] == 0:
            raise CdrError("big-endian CDR payloads are not supported")
        msg, pos = self.decode_from(buf, HEADER_SIZE)
        if len(buf) - pos > 8:
            raise CdrError(f"{len(buf) - pos} unexpected bytes after a {self.name} payload")
        return msg


@functools.cache
def compiled(name: str) -> MessageCodec:
    """The codec of message type ``name`` (compiled once, cached)."""
    codec = MessageCodec(name)
    codec._build()
    return codec


def serialize(msg: Any) -> bytes:
    """Encode a message instance to CDR bytes with header."""
    return compiled(msg.__msgtype__).serialize(msg)


def deserialize(data: bytes | bytearray | memoryview, name: str) -> Any:
    """Decode CDR bytes with header into a message of type ``name``; raise :class:`CdrError`."""
    return compiled(name).deserialize(data)

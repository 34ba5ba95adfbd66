"""A minimal reader and writer of Thrift's compact protocol, the encoding of Parquet's page headers and footer.

Only what :mod:`lerobot_focal.datasets.repair.parquet_footer` needs to rebuild a footer: structs are read into
``{field_id: (type, value)}`` dicts that keep each field's wire type, so they can be edited and written back.
Lists are ``(element_type, [values])``; maps ``(key_type, value_type, [(k, v), ...])``.

Why not a library: pyarrow reads and writes footers but exposes no way to write one for existing pages;
fastparquet's Thrift objects live in its internal ``cencoding`` module (no public API to build on); a generic
Thrift library (thriftpy2) would need Parquet's IDL file bundled with this project. The compact protocol is
small and fixed, and a rebuilt file is always checked by reading it back with pyarrow.
"""

from __future__ import annotations

import struct
from typing import Any

STOP, TRUE, FALSE, BYTE, I16, I32, I64, DOUBLE, BINARY, LIST, SET, MAP, STRUCT = range(13)

Struct = dict[int, tuple[int, Any]]


class Reader:
    def __init__(self, data: bytes | memoryview, pos: int = 0) -> None:
        self.data = memoryview(data)
        self.pos = pos

    def _byte(self) -> int:
        if self.pos >= len(self.data):
            raise EOFError("thrift: unexpected end of data")
        b = self.data[self.pos]
        self.pos += 1
        return b

    def varint(self) -> int:
        shift = result = 0
        while True:
            b = self._byte()
            result |= (b & 0x7F) << shift
            if not b & 0x80:
                return result
            shift += 7
            if shift > 70:
                raise ValueError("thrift: varint too long")

    def zigzag(self) -> int:
        n = self.varint()
        return (n >> 1) ^ -(n & 1)

    def value(self, kind: int) -> Any:
        if kind in (TRUE, FALSE):
            return self._byte() == TRUE  # inside a container a bool is its own byte
        if kind == BYTE:
            return struct.unpack("b", bytes([self._byte()]))[0]
        if kind in (I16, I32, I64):
            return self.zigzag()
        if kind == DOUBLE:
            if self.pos + 8 > len(self.data):
                raise EOFError("thrift: unexpected end of data")
            v = struct.unpack_from("<d", self.data, self.pos)[0]
            self.pos += 8
            return v
        if kind == BINARY:
            n = self.varint()
            if self.pos + n > len(self.data):
                raise EOFError("thrift: unexpected end of data")
            v = bytes(self.data[self.pos : self.pos + n])
            self.pos += n
            return v
        if kind in (LIST, SET):
            head = self._byte()
            size, elem = head >> 4, head & 0x0F
            if size == 15:
                size = self.varint()
            return (elem, [self.value(elem) for _ in range(size)])
        if kind == MAP:
            size = self.varint()
            if size == 0:
                return (0, 0, [])
            types = self._byte()
            kt, vt = types >> 4, types & 0x0F
            return (kt, vt, [(self.value(kt), self.value(vt)) for _ in range(size)])
        if kind == STRUCT:
            return self.struct()
        raise ValueError(f"thrift: unknown compact type {kind}")

    def struct(self) -> Struct:
        fields: Struct = {}
        last = 0
        while True:
            head = self._byte()
            kind = head & 0x0F
            if kind == STOP:
                return fields
            delta = head >> 4
            fid = last + delta if delta else self.zigzag()
            if kind in (TRUE, FALSE):
                fields[fid] = (TRUE, kind == TRUE)
            else:
                fields[fid] = (kind, self.value(kind))
            last = fid


class Writer:
    def __init__(self) -> None:
        self.out = bytearray()

    def varint(self, n: int) -> None:
        while True:
            if n < 0x80:
                self.out.append(n)
                return
            self.out.append((n & 0x7F) | 0x80)
            n >>= 7

    def zigzag(self, n: int) -> None:
        self.varint((n << 1) ^ (n >> 63))

    def value(self, kind: int, v: Any) -> None:
        if kind in (TRUE, FALSE):
            self.out.append(TRUE if v else FALSE)
        elif kind == BYTE:
            self.out += struct.pack("b", v)
        elif kind in (I16, I32, I64):
            self.zigzag(int(v))
        elif kind == DOUBLE:
            self.out += struct.pack("<d", v)
        elif kind == BINARY:
            b = v.encode() if isinstance(v, str) else bytes(v)
            self.varint(len(b))
            self.out += b
        elif kind in (LIST, SET):
            elem, items = v
            if len(items) < 15:
                self.out.append((len(items) << 4) | elem)
            else:
                self.out.append(0xF0 | elem)
                self.varint(len(items))
            for item in items:
                self.value(elem, item)
        elif kind == MAP:
            kt, vt, items = v
            self.varint(len(items))
            if items:
                self.out.append((kt << 4) | vt)
                for k, val in items:
                    self.value(kt, k)
                    self.value(vt, val)
        elif kind == STRUCT:
            self.struct(v)
        else:
            raise ValueError(f"thrift: unknown compact type {kind}")

    def struct(self, fields: Struct) -> None:
        last = 0
        for fid in sorted(fields):
            kind, v = fields[fid]
            wire = (TRUE if v else FALSE) if kind in (TRUE, FALSE) else kind
            if 0 < fid - last <= 15:
                self.out.append(((fid - last) << 4) | wire)
            else:
                self.out.append(wire)
                self.zigzag(fid)
            if kind not in (TRUE, FALSE):
                self.value(kind, v)
            last = fid
        self.out.append(STOP)


def encode_struct(fields: Struct) -> bytes:
    w = Writer()
    w.struct(fields)
    return bytes(w.out)

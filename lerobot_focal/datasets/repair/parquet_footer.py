"""Rebuild the footer of a Parquet file whose writer was killed before closing it.

A Parquet file is ``PAR1``, then row groups (per column: an optional dictionary page and data pages, each a
Thrift page header followed by the page bytes), then the footer (the file's schema and where every column
chunk of every row group starts) and ``PAR1``. The footer is written last, when the file is closed, so a
killed writer leaves row groups no reader can find. LeRobot's dataset writer adds one row group per saved
episode, so the finished episodes are all in the file; only the map to them is missing.

:func:`rebuild_footer` walks the page headers from the start of the file and writes the map again. What it
needs to know besides the bytes: the schema (a footer of an empty file written with the same Arrow schema
supplies it) and how many leaf values each column holds per row (a (9,) float feature: 9). A row group
cut off by the kill is dropped. The result is checked by reading it back with pyarrow.
"""

from __future__ import annotations

import io
import struct
from dataclasses import dataclass, field
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from lerobot_focal.datasets.repair import thrift_compact as tc

MAGIC = b"PAR1"
DATA_PAGE, INDEX_PAGE, DICTIONARY_PAGE, DATA_PAGE_V2 = 0, 1, 2, 3
# Tried in this order when the rebuilt file is read back; LeRobot writes snappy.
CODECS = {"SNAPPY": 1, "UNCOMPRESSED": 0, "ZSTD": 6, "GZIP": 2, "LZ4_RAW": 7, "BROTLI": 4}


class FooterRebuildError(RuntimeError):
    """The file's pages do not fit the given schema; nothing was written."""


@dataclass
class _Chunk:
    start: int
    dictionary_offset: int | None = None
    data_offset: int | None = None
    values: int = 0
    compressed: int = 0
    uncompressed: int = 0
    encodings: set[int] = field(default_factory=set)


@dataclass
class Leaf:
    path: list[str]
    physical_type: int
    values_per_row: int


def template_footer(schema: pa.Schema) -> tc.Struct:
    """The footer pyarrow writes for an empty file of `schema` (schema elements, Arrow schema metadata)."""
    buf = io.BytesIO()
    with pq.ParquetWriter(buf, schema=schema, compression="snappy", use_dictionary=True):
        pass
    data = buf.getvalue()
    (length,) = struct.unpack("<I", data[-8:-4])
    return tc.Reader(data[-8 - length : -8]).struct()


def leaves_of(footer: tc.Struct) -> list[tuple[list[str], int]]:
    """(path, physical type) of each leaf column, in file order, from a footer's schema elements."""
    elements = footer[2][1][1]
    out: list[tuple[list[str], int]] = []

    def walk(i: int, prefix: list[str]) -> int:
        el = elements[i]
        name = el[4][1].decode()
        children = el.get(5, (0, 0))[1]
        path = [*prefix, name] if i > 0 else []
        if not children and i > 0:
            out.append((path, el[1][1]))
            return i + 1
        j = i + 1
        for _ in range(children):
            j = walk(j, path)
        return j

    walk(0, [])
    return out


def _page(data: memoryview, pos: int) -> tuple[tc.Struct, int]:
    reader = tc.Reader(data, pos)
    header = reader.struct()
    size = header.get(3, (0, -1))[1]
    kind = header.get(1, (0, -1))[1]
    if kind not in (DATA_PAGE, INDEX_PAGE, DICTIONARY_PAGE, DATA_PAGE_V2) or size < 0:
        raise ValueError("not a page header")
    end = reader.pos + size
    if end > len(data):
        raise EOFError("page runs past the end of the file")
    return header, reader.pos - pos


def _add_page(chunk: _Chunk, pos: int, header: tc.Struct, header_len: int) -> None:
    kind = header[1][1]
    chunk.compressed += header_len + header[3][1]
    chunk.uncompressed += header_len + header[2][1]
    if kind == DICTIONARY_PAGE:
        chunk.dictionary_offset = pos
        chunk.encodings.add(header[7][1].get(2, (0, 0))[1])
        return
    if chunk.data_offset is None:
        chunk.data_offset = pos
    sub = header.get(5) or header.get(8)
    if sub is not None:
        chunk.values += sub[1][1][1]
        chunk.encodings.add(sub[1].get(4 if kind == DATA_PAGE_V2 else 2, (0, 0))[1])


def scan_row_groups(data: bytes, leaves: list[Leaf]) -> tuple[list[tuple[int, int, list[_Chunk]]], int]:
    """Complete row groups as (start, rows, column chunks), and the offset where the last one ends."""
    view = memoryview(data)
    if bytes(view[:4]) != MAGIC:
        raise FooterRebuildError("not a Parquet file (no PAR1 at the start)")
    groups: list[tuple[int, int, list[_Chunk]]] = []
    pos = end_ok = 4
    while pos < len(view):
        start, rows, chunks = pos, None, []
        try:
            for i, leaf in enumerate(leaves):
                chunk = _Chunk(start=pos)
                while True:
                    header, hlen = _page(view, pos)
                    kind = header[1][1]
                    if i == 0 and rows is None and kind == DICTIONARY_PAGE and chunk.data_offset is not None:
                        # The next column's dictionary page: column 0 ends here and tells the row count.
                        if chunk.values % leaf.values_per_row:
                            raise FooterRebuildError(
                                f"column {'.'.join(leaf.path)}: {chunk.values} values is not a whole number of "
                                f"rows of {leaf.values_per_row}"
                            )
                        rows = chunk.values // leaf.values_per_row
                        break
                    _add_page(chunk, pos, header, hlen)
                    pos += hlen + header[3][1]
                    if i > 0 and chunk.values >= rows * leaf.values_per_row:
                        break
                if i > 0 and chunk.values != rows * leaf.values_per_row:
                    raise FooterRebuildError(
                        f"column {'.'.join(leaf.path)} holds {chunk.values} values in a row group of {rows} rows "
                        f"(expected {rows * leaf.values_per_row})"
                    )
                chunks.append(chunk)
        except (EOFError, ValueError):
            break  # the kill cut this row group (or its header) short: it is not recoverable
        groups.append((start, rows, chunks))
        end_ok = pos
    return groups, end_ok


def _footer(template: tc.Struct, leaves: list[Leaf], groups, codec: int) -> bytes:
    row_groups = []
    for ordinal, (start, rows, chunks) in enumerate(groups):
        columns = []
        for leaf, c in zip(leaves, chunks, strict=True):
            meta: tc.Struct = {
                1: (tc.I32, leaf.physical_type),
                2: (tc.LIST, (tc.I32, sorted(c.encodings | {3}))),  # + RLE for the levels
                3: (tc.LIST, (tc.BINARY, [p.encode() for p in leaf.path])),
                4: (tc.I32, codec),
                5: (tc.I64, c.values),
                6: (tc.I64, c.uncompressed),
                7: (tc.I64, c.compressed),
                9: (tc.I64, c.data_offset),
            }
            if c.dictionary_offset is not None:
                meta[11] = (tc.I64, c.dictionary_offset)
            columns.append({2: (tc.I64, c.start), 3: (tc.STRUCT, meta)})
        row_groups.append({
            1: (tc.LIST, (tc.STRUCT, columns)),
            2: (tc.I64, sum(c.uncompressed for c in chunks)),
            3: (tc.I64, rows),
            5: (tc.I64, start),
            6: (tc.I64, sum(c.compressed for c in chunks)),
            7: (tc.I16, ordinal),
        })
    footer = {k: v for k, v in template.items() if k in (1, 2, 5, 6, 7)}
    footer[3] = (tc.I64, sum(rows for _, rows, _ in groups))
    footer[4] = (tc.LIST, (tc.STRUCT, row_groups))
    return tc.encode_struct(footer)


def rebuild_footer(src: str | Path, dst: str | Path, schema: pa.Schema, values_per_row: dict[str, int]) -> pa.Table:
    """Write `dst`: the complete row groups of footerless `src` with a new footer; returns its table.

    `values_per_row` maps each top-level column to its leaf values per row (per leaf when a column has several,
    e.g. an image struct's bytes and path: 1 each).
    """
    data = Path(src).read_bytes()
    template = template_footer(schema)
    leaves = [Leaf(path, ptype, values_per_row[path[0]]) for path, ptype in leaves_of(template)]
    groups, end = scan_row_groups(data, leaves)
    if not groups:
        raise FooterRebuildError(f"{src}: no complete row group before the point where the file breaks off")
    errors = []
    for name, codec in CODECS.items():
        footer = _footer(template, leaves, groups, codec)
        Path(dst).write_bytes(data[:end] + footer + struct.pack("<I", len(footer)) + MAGIC)
        try:
            return pq.read_table(dst)
        except Exception as exc:  # noqa: BLE001 - a wrong codec guess shows up as any decoding error
            errors.append(f"{name}: {exc}")
    Path(dst).unlink(missing_ok=True)
    raise FooterRebuildError(f"{src}: the rebuilt file does not read back ({'; '.join(errors)})")

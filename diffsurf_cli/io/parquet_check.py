"""A check of a Parquet file's structure before polars reads it (issue 32).

polars trusts the counts and sizes a Parquet file states: a data page header whose value count
is negative or huge makes it ask for 2**61 bytes, and the process aborts (SIGABRT), which no
Python code can catch. :func:`check_parquet` reads what polars would trust, in pure Python, and
refuses the file (a ValueError that says what is wrong, one line) before polars sees it:

- the footer: PAR1 at the end, its length within the file, the FileMetaData (Thrift compact
  protocol, decoded by `_Thrift`: every read bounds-checked, nesting depth limited, unknown
  fields skipped), the schema tree, the row groups' row counts (non-negative, summing to the
  file's);
- every column chunk of every row group: its byte range within the file's data, its value count
  (a column outside any repeated group has one value per row);
- every page of every chunk, walked from the chunk's first page to its end: the header decodes,
  the sizes are non-negative and the page lies within its chunk; a data page (v1 or v2) holds no
  more values than its chunk, and a column outside any repeated group no more than the row
  group's rows; a dictionary page's value count fits its bytes; the data pages' value counts sum
  to the chunk's.

The work is linear in the number of pages and reads only the footer and the page headers (the
file is memory mapped): milliseconds for a file of 200 000 rows. It checks the structure, not
the values: an encoding or codec polars does not know, or damaged compressed data, is left to
polars, which raises (or panics, which the caller catches) for those.
"""
from __future__ import annotations

import mmap
import os
import struct

__all__ = ["check_parquet"]

MAGIC = b"PAR1"
#: the last four bytes of a Parquet file whose footer is encrypted.
MAGIC_ENCRYPTED = b"PARE"
#: how deep Thrift structs, lists and maps may nest (the Parquet metadata nests to about 5).
MAX_DEPTH = 16
#: how many values a chunk of a column inside a repeated group (a list) may claim beyond one a
#: row and eight a byte (run-length encoded levels make long lists of nulls cheap to store):
#: enough for any file a person writes, far below what would exhaust the memory.
NESTED_SLACK = 1 << 26

# Thrift compact protocol type codes
_TRUE, _FALSE, _BYTE, _I16, _I32, _I64, _DOUBLE, _BINARY, _LIST, _SET, _MAP, _STRUCT = range(
    1, 13)
_INTEGERS = (_BYTE, _I16, _I32, _I64)
#: bounds of the integer types, for the values a varint of each may carry.
_LIMITS = {_BYTE: 1 << 7, _I16: 1 << 15, _I32: 1 << 31, _I64: 1 << 63}

# Parquet page types and codecs
_DATA_PAGE, _INDEX_PAGE, _DICTIONARY_PAGE, _DATA_PAGE_V2 = range(4)
_UNCOMPRESSED = 0
_REPEATED = 2


class _Thrift:
    """A reader of the Thrift compact protocol over ``buf[pos:end]``: structs decode to dicts
    of field id to value (ints, bools, floats, bytes, lists, dicts; a map is a list of pairs).
    Every read is checked against ``end`` and every integer against its type's range; a
    violation raises ValueError."""

    __slots__ = ("buf", "pos", "end")

    def __init__(self, buf, pos: int, end: int):
        self.buf, self.pos, self.end = buf, pos, end

    def _byte(self) -> int:
        if self.pos >= self.end:
            raise ValueError("truncated")
        b = self.buf[self.pos]
        self.pos += 1
        return b

    def _varint(self) -> int:
        shift = result = 0
        while True:
            b = self._byte()
            result |= (b & 0x7F) << shift
            if not b & 0x80:
                return result
            shift += 7
            if shift >= 70:
                raise ValueError("a varint longer than 10 bytes")

    def _int(self, kind: int) -> int:
        if kind == _BYTE:
            b = self._byte()
            return b - 256 if b >= 128 else b
        n = self._varint()
        value = (n >> 1) ^ -(n & 1)
        if not -_LIMITS[kind] <= value < _LIMITS[kind]:
            raise ValueError("an integer out of range")
        return value

    def _size(self) -> int:
        n = self._varint()
        # every element takes at least one byte: a size beyond the bytes left is a lie
        if n > self.end - self.pos:
            raise ValueError("a list longer than its bytes")
        return n

    def value(self, kind: int, depth: int):
        if kind in _INTEGERS:
            return self._int(kind)
        if kind == _BINARY:
            n = self._size()
            start = self.pos
            self.pos += n
            return bytes(self.buf[start:self.pos])
        if kind == _STRUCT:
            return self.struct(depth + 1)
        if kind in (_LIST, _SET):
            return self._list(depth + 1)
        if kind == _MAP:
            return self._map(depth + 1)
        if kind == _DOUBLE:
            if self.end - self.pos < 8:
                raise ValueError("truncated")
            self.pos += 8
            return struct.unpack_from("<d", self.buf, self.pos - 8)[0]
        raise ValueError(f"an unknown Thrift type {kind}")

    def _element(self, kind: int, depth: int):
        if kind in (_TRUE, _FALSE):  # a bool in a list is a whole byte
            b = self._byte()
            if b not in (0, 1, 2):
                raise ValueError("a bad boolean")
            return b == 1
        return self.value(kind, depth)

    def _list(self, depth: int) -> list:
        if depth > MAX_DEPTH:
            raise ValueError("nested too deep")
        head = self._byte()
        n, kind = head >> 4, head & 0x0F
        if n == 15:
            n = self._size()
        elif n > self.end - self.pos:
            raise ValueError("a list longer than its bytes")
        return [self._element(kind, depth) for _ in range(n)]

    def _map(self, depth: int) -> list:
        """A map as a list of (key, value) pairs (Parquet's metadata has none: it is skipped)."""
        if depth > MAX_DEPTH:
            raise ValueError("nested too deep")
        n = self._size()
        if n == 0:
            return []
        head = self._byte()
        kinds = head >> 4, head & 0x0F
        return [(self._element(kinds[0], depth), self._element(kinds[1], depth))
                for _ in range(n)]

    def struct(self, depth: int = 0) -> dict:
        if depth > MAX_DEPTH:
            raise ValueError("nested too deep")
        fields = {}
        last = 0
        while True:
            head = self._byte()
            if head == 0:
                return fields
            delta, kind = head >> 4, head & 0x0F
            fid = last + delta if delta else self._int(_I16)
            if kind == _TRUE:
                fields[fid] = True
            elif kind == _FALSE:
                fields[fid] = False
            else:
                fields[fid] = self.value(kind, depth)
            last = fid


def _int(fields: dict, fid: int, what: str, required: bool = True, low: int = 0):
    """Field `fid` of a decoded struct as an int >= `low` (None if absent and not required)."""
    value = fields.get(fid)
    if value is None and not required:
        return None
    if type(value) is not int:
        raise ValueError(f"{what} {'missing' if value is None else 'not an integer'}")
    if value < low:
        raise ValueError(f"{what} {value}")
    return value


def _list_of_structs(fields: dict, fid: int, what: str) -> list:
    value = fields.get(fid)
    if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
        raise ValueError(f"{what} {'missing' if value is None else 'malformed'}")
    return value


def _leaves(schema: list) -> list[bool]:
    """For each leaf column of the schema (depth first, the order of a row group's column
    chunks): whether it lies inside a repeated field (a list), i.e. may hold several values a
    row. The tree is walked with a stack: no recursion, however deep it claims to be."""
    if not schema:
        raise ValueError("an empty schema")
    leaves = []
    root = schema[0]
    children = _int(root, 5, "the schema root's child count")
    stack = [(children, False)]  # (children left to read, inside a repeated field)
    i = 1
    while stack:
        left, repeated = stack[-1]
        if left == 0:
            stack.pop()
            continue
        stack[-1] = (left - 1, repeated)
        if i >= len(schema):
            raise ValueError("the schema has fewer elements than its groups claim")
        element = schema[i]
        i += 1
        inside = repeated or element.get(3) == _REPEATED
        n = _int(element, 5, "a schema child count", required=False)
        if n is None:
            leaves.append(inside)
        else:
            if n > len(schema) - i:
                raise ValueError("the schema has fewer elements than its groups claim")
            stack.append((n, inside))
    if i != len(schema):
        raise ValueError("the schema has elements outside its tree")
    return leaves


def _page_header(buf, pos: int, end: int) -> tuple[dict, int]:
    reader = _Thrift(buf, pos, end)
    try:
        header = reader.struct()
    except ValueError as exc:
        raise ValueError(f"a page header at byte {pos} does not decode: {exc}") from None
    return header, reader.pos


def _check_chunk(buf, meta: dict, rows: int, repeated: bool, data_end: int, where: str) -> None:
    """Walk the pages of one column chunk (`meta`: its ColumnMetaData) in ``buf``."""
    codec = _int(meta, 4, f"{where}: codec")
    values = _int(meta, 5, f"{where}: value count")
    uncompressed = _int(meta, 6, f"{where}: uncompressed size")
    compressed = _int(meta, 7, f"{where}: compressed size")
    first = _int(meta, 9, f"{where}: data page offset")
    dictionary = _int(meta, 11, f"{where}: dictionary page offset", required=False, low=-1)
    # the chunk starts at its first page: the dictionary page if any, else the first data
    # page (pyarrow writes a data page offset 0 for a chunk of no rows, a dictionary page only)
    starts = [at for at in (first, dictionary) if at is not None and at >= len(MAGIC)]
    first = min(starts, default=first)
    if repeated:
        if values > rows + 8 * uncompressed + NESTED_SLACK:
            raise ValueError(f"{where}: {values} values in {uncompressed} bytes")
    elif values != rows:
        raise ValueError(f"{where}: {values} values for {rows} rows")
    end = first + compressed
    # a chunk of no bytes has no pages to read, wherever it says it is (pyarrow writes offset 0
    # for a column of no rows)
    if compressed and (first < len(MAGIC) or end > data_end):
        raise ValueError(f"{where}: bytes {first} to {end} outside the data (bytes 4 to "
                         f"{data_end})")
    # a page of a column outside any repeated group holds at most one value a row
    most = values if repeated else rows
    pos, seen = first, 0
    while pos < end:
        header, body = _page_header(buf, pos, end)
        at = f"{where}, page at byte {pos}"
        kind = _int(header, 1, f"{at}: type")
        size = _int(header, 2, f"{at}: uncompressed size")
        stored = _int(header, 3, f"{at}: compressed size")
        if stored > end - body:
            raise ValueError(f"{at}: {stored} bytes, beyond its column chunk")
        if size > uncompressed or (codec == _UNCOMPRESSED and size != stored):
            raise ValueError(f"{at}: uncompressed size {size}")
        if kind in (_DATA_PAGE, _DATA_PAGE_V2, _DICTIONARY_PAGE):
            fid = {_DATA_PAGE: 5, _DICTIONARY_PAGE: 7, _DATA_PAGE_V2: 8}[kind]
            sub = header.get(fid)
            if not isinstance(sub, dict):
                raise ValueError(f"{at}: no page header of its type {kind}")
            n = _int(sub, 1, f"{at}: value count")
            if kind == _DICTIONARY_PAGE:
                if n > 8 * size + 8:  # a value takes a byte at least, a bit if boolean
                    raise ValueError(f"{at}: {n} dictionary values in {size} bytes")
            else:
                if n > most:
                    raise ValueError(f"{at}: value count {n} (the column chunk has {most})")
                seen += n
            if kind == _DATA_PAGE_V2:
                _int(sub, 2, f"{at}: null count")
                page_rows = _int(sub, 3, f"{at}: row count")
                if sub[2] > n or page_rows > rows:
                    raise ValueError(f"{at}: {sub[2]} nulls, {page_rows} rows in {n} values")
                levels = (_int(sub, 5, f"{at}: definition levels' length")
                          + _int(sub, 6, f"{at}: repetition levels' length"))
                if levels > stored or levels > size:
                    raise ValueError(f"{at}: {levels} bytes of levels in {stored}")
        pos = body + stored
    if seen != values:
        raise ValueError(f"{where}: its pages hold {seen} values, its metadata says {values}")


def _check(buf, size: int) -> None:
    if size < 3 * len(MAGIC):
        raise ValueError(f"{size} bytes, too short")
    tail = bytes(buf[size - 4:size])
    if tail == MAGIC_ENCRYPTED:
        raise ValueError("its footer is encrypted")
    if tail != MAGIC:
        raise ValueError("it does not end with PAR1")
    length = struct.unpack_from("<I", buf, size - 8)[0]
    data_end = size - 8 - length
    if data_end < len(MAGIC):
        raise ValueError(f"a footer of {length} bytes in a file of {size}")
    try:
        meta = _Thrift(buf, data_end, size - 8).struct()
    except ValueError as exc:
        raise ValueError(f"the footer does not decode: {exc}") from None
    total = _int(meta, 3, "the row count")
    leaves = _leaves(_list_of_structs(meta, 2, "the schema"))
    groups = _list_of_structs(meta, 4, "the row groups")
    counted = 0
    for g, group in enumerate(groups):
        rows = _int(group, 3, f"row group {g}: row count")
        counted += rows
        chunks = _list_of_structs(group, 1, f"row group {g}: columns")
        if len(chunks) != len(leaves):
            raise ValueError(f"row group {g}: {len(chunks)} column chunks for {len(leaves)} "
                             f"columns")
        for c, (chunk, repeated) in enumerate(zip(chunks, leaves)):
            where = f"row group {g}, column {c}"
            if chunk.get(1) is not None:
                raise ValueError(f"{where}: its data is in another file")
            meta_data = chunk.get(3)
            if not isinstance(meta_data, dict):
                raise ValueError(f"{where}: no column metadata")
            _check_chunk(buf, meta_data, rows, repeated, data_end, where)
    if counted != total:
        raise ValueError(f"the row groups hold {counted} rows, the footer says {total}")


def check_parquet(path: str) -> None:
    """Check the structure of the Parquet file at `path` (see the module's docstring): return
    if polars may be given it, else raise ValueError saying what is wrong (one line, no file
    name). An OSError reading the file passes through."""
    with open(path, "rb") as fh:
        size = os.fstat(fh.fileno()).st_size
        try:
            buf = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
        except (OSError, ValueError):  # not a regular file, or no mapping here: read it
            buf = fh.read()
            size = len(buf)
        try:
            _check(buf, size)
        finally:
            if isinstance(buf, mmap.mmap):
                buf.close()

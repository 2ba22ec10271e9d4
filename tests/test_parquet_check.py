"""Issue 32, item 7: the check of a Parquet file's structure before polars reads it
(diffsurf_cli/io/parquet_check.py). Every file polars or pyarrow writes passes it (every codec,
several row groups, dictionary on or off, data page v1 / v2, statistics, nulls, nested
columns); a file whose footer or page headers lie (a huge or negative value count, a negative
size, an offset beyond the file, a truncated footer ...) is refused with one line saying what,
and `read_contactors` turns that into a ReadError naming the file, before polars could abort
the process on it.

The damaged files are built here from scratch by a small Thrift compact protocol writer, so
that each lie is exactly one field; the undamaged build is checked to read (polars and
pyarrow) to the values written."""
from __future__ import annotations

import itertools
import struct
import time

import numpy as np
import pytest

from diffsurf_cli import io
from diffsurf_cli.io.parquet_check import check_parquet

pl = pytest.importorskip("polars")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

CODECS = ["uncompressed", "snappy", "gzip", "lz4", "zstd", "brotli"]


# --------------------------------------------------------------------------------------------
# a Thrift compact protocol writer: values are (kind, value) pairs
# --------------------------------------------------------------------------------------------

_CODES = {"true": 1, "false": 2, "i32": 5, "i64": 6, "bin": 8, "list": 9, "struct": 12}


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        if n < 0x80:
            out.append(n)
            return bytes(out)
        out.append(n & 0x7F | 0x80)
        n >>= 7


def _zigzag(n: int) -> bytes:
    return _varint((n << 1) ^ (n >> 63))


def _value(kind: str, value) -> bytes:
    if kind in ("i32", "i64"):
        return _zigzag(value)
    if kind == "bin":
        data = value.encode() if isinstance(value, str) else value
        return _varint(len(data)) + data
    if kind == "list":
        elem, items = value
        head = (bytes([len(items) << 4 | _CODES[elem]]) if len(items) < 15
                else bytes([0xF0 | _CODES[elem]]) + _varint(len(items)))
        return head + b"".join(_value(elem, v) for v in items)
    if kind == "struct":
        return _struct(value)
    raise AssertionError(kind)


def _struct(fields: dict) -> bytes:
    out, last = bytearray(), 0
    for fid in sorted(fields):
        kind, value = fields[fid]
        if kind == "bool":
            kind = "true" if value else "false"
        delta = fid - last
        code = _CODES[kind]
        out += bytes([delta << 4 | code]) if 0 < delta < 16 else bytes([code]) + _zigzag(fid)
        if kind not in ("true", "false"):
            out += _value(kind, value)
        last = fid
    return bytes(out + b"\x00")


# --------------------------------------------------------------------------------------------
# a Parquet file from scratch: columns x, y, z (required doubles), one uncompressed data page
# each, in row groups of the given sizes
# --------------------------------------------------------------------------------------------


def build(groups=(3,), *, page=None, chunk=None, group=None, meta=None, footer=None,
          dictionary=None):
    """The bytes of a valid Parquet file, each row i holding x = i, y = 10 i, z = 100 i; the
    hooks change the PageHeader, ColumnMetaData, RowGroup and FileMetaData field dicts
    (``page(fields, g, c)`` ...) or the encoded footer (``footer(bytes)``); ``dictionary`` puts
    a dictionary page header (with that DictionaryPageHeader dict) before each first page."""
    data = bytearray(b"PAR1")
    row_groups, first = [], 0
    for g, rows in enumerate(groups):
        chunks = []
        for c, scale in enumerate((1.0, 10.0, 100.0)):
            start = len(data)
            if dictionary is not None:
                data += _struct({1: ("i32", 2), 2: ("i32", 0), 3: ("i32", 0),
                                 7: ("struct", dict(dictionary))})
            body = np.arange(first, first + rows, dtype="<f8").tobytes() if rows else b""
            body = (np.frombuffer(body, "<f8") * scale).tobytes()
            header = {1: ("i32", 0), 2: ("i32", len(body)), 3: ("i32", len(body)),
                      5: ("struct", {1: ("i32", rows), 2: ("i32", 0), 3: ("i32", 3),
                                     4: ("i32", 3)})}
            if page is not None:
                page(header, g, c)
            data_offset = len(data)
            data += _struct(header) + body
            size = len(data) - start
            column = {1: ("i32", 5), 2: ("list", ("i32", [0, 3])), 3: ("list", ("bin", ["xyz"[c]])),
                      4: ("i32", 0), 5: ("i64", rows), 6: ("i64", size), 7: ("i64", size),
                      9: ("i64", data_offset)}
            if dictionary is not None:
                column[11] = ("i64", start)
            if chunk is not None:
                chunk(column, g, c)
            chunks.append({2: ("i64", start), 3: ("struct", column)})
        fields = {1: ("list", ("struct", chunks)), 2: ("i64", 24 * rows), 3: ("i64", rows)}
        if group is not None:
            group(fields, g)
        row_groups.append(fields)
        first += rows
    schema = [{4: ("bin", "schema"), 5: ("i32", 3)}] + [
        {1: ("i32", 5), 3: ("i32", 0), 4: ("bin", name)} for name in "xyz"]
    fields = {1: ("i32", 1), 2: ("list", ("struct", schema)), 3: ("i64", sum(groups)),
              4: ("list", ("struct", row_groups)), 6: ("bin", "diffsurf test")}
    if meta is not None:
        meta(fields)
    encoded = _struct(fields)
    if footer is not None:
        encoded = footer(encoded)
    return bytes(data + encoded + struct.pack("<I", len(encoded)) + b"PAR1")


def write(tmp_path, data: bytes, name="t.parquet") -> str:
    path = tmp_path / name
    path.write_bytes(data)
    return str(path)


def refused(tmp_path, data: bytes, what: str) -> str:
    """Check that the file is refused with `what` in the reason, by the check and by
    read_contactors (a one-line ReadError naming the file); the reason."""
    path = write(tmp_path, data)
    with pytest.raises(ValueError) as info:
        check_parquet(path)
    reason = str(info.value)
    assert what in reason and "\n" not in reason, reason
    with pytest.raises(io.ReadError) as info:
        io.read_contactors(path)
    message = str(info.value)
    assert message.startswith(f"{path}: not a valid Parquet file ("), message
    assert what in message and "\n" not in message, message
    return reason


# --------------------------------------------------------------------------------------------
# valid files pass
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("groups", [(3,), (2, 5, 1), (0,), ()])
def test_the_built_file_is_valid_parquet(tmp_path, groups):
    path = write(tmp_path, build(groups))
    check_parquet(path)
    n = sum(groups)
    expected = {"x": np.arange(n) * 1.0, "y": np.arange(n) * 10.0, "z": np.arange(n) * 100.0}
    for frame in (pl.read_parquet(path), pl.from_arrow(pq.read_table(path))):
        for name, values in expected.items():
            assert frame[name].to_numpy().tolist() == values.tolist()
    if n:
        assert io.read_contactors(path).points[:, 2].tolist() == expected["z"].tolist()


def _frame(n: int = 3000):
    rng = np.random.default_rng(7)
    return pl.DataFrame({
        "x": rng.normal(size=n), "y": [None if i % 7 == 0 else float(i) for i in range(n)],
        "z": np.zeros(n), "id": [f"p{i % 50}" for i in range(n)],
        "list": [[i, None, 3] if i % 3 else None for i in range(n)],
        "struct": [{"a": i, "b": [str(i)] * (i % 4)} for i in range(n)],
        "nulls": [[None] * 500 if i < 20 else [] for i in range(n)],
        "flag": [i % 2 == 0 for i in range(n)],
        "array": pl.Series([[i, i + 1] for i in range(n)], dtype=pl.Array(pl.Int32, 2)),
        "date": pl.Series(range(n), dtype=pl.Int32).cast(pl.Date),
        "nothing": pl.Series([None] * n, dtype=pl.Null)})


@pytest.mark.parametrize("codec", CODECS)
def test_files_polars_writes_pass(tmp_path, codec):
    frame = _frame()
    path = str(tmp_path / "p.parquet")
    for group, stats in itertools.product([None, 700], [True, False]):
        frame.write_parquet(path, compression=codec, row_group_size=group, statistics=stats,
                            data_page_size=None if group is None else 1000)
        check_parquet(path)
    c = io.read_contactors(path)
    assert np.array_equal(c.points[:, 0], frame["x"].to_numpy())


@pytest.mark.parametrize("codec", CODECS)
def test_files_pyarrow_writes_pass(tmp_path, codec):
    table = _frame().drop("nothing").to_arrow()
    path = str(tmp_path / "a.parquet")
    for dictionary, version, page, group in itertools.product(
            [True, False], ["1.0", "2.0"], [None, 64], [None, 900]):
        pq.write_table(table, path, compression="none" if codec == "uncompressed" else codec,
                       row_group_size=group, use_dictionary=dictionary,
                       data_page_version=version, data_page_size=page,
                       write_statistics=dictionary, write_page_index=page is None)
        check_parquet(path)
    # a dictionary array with entries no row uses, written as they are
    values = pa.array(["a", "b", "c", "d"] * 10)
    dict_table = pa.table({"x": np.arange(3.0), "y": np.zeros(3), "z": np.ones(3),
                           "k": pa.DictionaryArray.from_arrays(pa.array([0, 0, 1]), values)})
    pq.write_table(dict_table, path, compression="none" if codec == "uncompressed" else codec)
    check_parquet(path)


def test_an_empty_table_passes(tmp_path):
    path = str(tmp_path / "e.parquet")
    pl.DataFrame({"x": [], "y": [], "z": []}, schema={a: pl.Float64 for a in "xyz"}
                 ).write_parquet(path)
    check_parquet(path)
    for dictionary in (True, False):
        pq.write_table(pa.table({"x": pa.array([], pa.float64())}), path,
                       use_dictionary=dictionary)
        check_parquet(path)


def test_the_check_is_fast(tmp_path):
    rng = np.random.default_rng(1)
    n = 200_000
    frame = pl.DataFrame({"x": rng.normal(size=n), "y": rng.normal(size=n),
                          "z": rng.normal(size=n), "id": np.arange(n)})
    path = str(tmp_path / "big.parquet")
    frame.write_parquet(path)
    best = min(_timed(check_parquet, path) for _ in range(3))
    assert best < 0.05, best


def _timed(f, *args) -> float:
    start = time.perf_counter()
    f(*args)
    return time.perf_counter() - start


# --------------------------------------------------------------------------------------------
# lies are refused
# --------------------------------------------------------------------------------------------


def _set(fid, kind, value, where=None):
    """A hook that sets field `fid` (of the first chunk, or of chunk `where`)."""
    def hook(fields, *at):
        if where is None or tuple(at) == where:
            fields[fid] = (kind, value)
    return hook


@pytest.mark.parametrize("count", [-64, -1, 4, 1 << 20, (1 << 31) - 1])
def test_a_data_page_value_count_beyond_the_rows_is_refused(tmp_path, count):
    refused(tmp_path, build(page=lambda h, g, c: h.update(
        {5: ("struct", {1: ("i32", count), 2: ("i32", 0), 3: ("i32", 3), 4: ("i32", 3)})})),
        f"value count {count}")


@pytest.mark.parametrize("count", [-5, (1 << 31) - 1])
def test_a_data_page_v2_value_count_is_checked(tmp_path, count):
    def v2(header, g, c):
        header[1] = ("i32", 3)
        del header[5]
        header[8] = ("struct", {1: ("i32", count), 2: ("i32", 0), 3: ("i32", 3),
                                4: ("i32", 0), 5: ("i32", 0), 6: ("i32", 0)})
    refused(tmp_path, build(page=v2), f"value count {count}")


def test_data_page_v2_levels_beyond_the_page_are_refused(tmp_path):
    def v2(header, g, c):
        header[1] = ("i32", 3)
        del header[5]
        header[8] = ("struct", {1: ("i32", 3), 2: ("i32", 0), 3: ("i32", 3),
                                4: ("i32", 0), 5: ("i32", 1 << 30), 6: ("i32", 0)})
    refused(tmp_path, build(page=v2), "bytes of levels")


def test_a_huge_dictionary_value_count_is_refused(tmp_path):
    refused(tmp_path, build(dictionary={1: ("i32", (1 << 31) - 1), 2: ("i32", 0)}),
            "dictionary values in 0 bytes")


def test_a_negative_dictionary_value_count_is_refused(tmp_path):
    refused(tmp_path, build(dictionary={1: ("i32", -3), 2: ("i32", 0)}), "value count -3")


@pytest.mark.parametrize("fid, what", [(2, "uncompressed size -8"), (3, "compressed size -8")])
def test_negative_page_sizes_are_refused(tmp_path, fid, what):
    refused(tmp_path, build(page=_set(fid, "i32", -8, (0, 1))), what)


def test_a_page_beyond_its_chunk_is_refused(tmp_path):
    refused(tmp_path, build(page=lambda h, g, c: h.update({3: ("i32", 1000)}) if c == 2 else
                            None, chunk=lambda m, g, c: c == 2 and m.update({6: ("i64", 10**6)})),
            "beyond its column chunk")


def test_a_page_larger_than_its_chunk_is_refused(tmp_path):
    refused(tmp_path, build(page=_set(2, "i32", (1 << 31) - 1, (0, 0))), "uncompressed size")


def test_an_undecodable_page_header_is_refused(tmp_path):
    # the data page offset 3 bytes into the header: 0x30 reads as a field of type 0
    refused(tmp_path, build(chunk=_set(9, "i64", 7, (0, 0))),
            "page header at byte 7 does not decode: an unknown Thrift type 0")


@pytest.mark.parametrize("fid, value, what", [
    (9, 1 << 40, "outside the data"), (9, -3, "data page offset -3"),
    (7, 1 << 40, "outside the data"), (7, -1, "compressed size -1"),
    (5, 1 << 40, "values for 3 rows"), (5, -2, "value count -2"),
    (6, -9, "uncompressed size -9")])
def test_column_chunk_lies_are_refused(tmp_path, fid, value, what):
    refused(tmp_path, build(chunk=_set(fid, "i64", value, (0, 1))), what)


def test_pages_holding_fewer_values_than_the_chunk_are_refused(tmp_path):
    refused(tmp_path, build(page=lambda h, g, c: h[5][1].update({1: ("i32", 2)})),
            "its pages hold 2 values, its metadata says 3")


def test_row_counts_are_checked(tmp_path):
    refused(tmp_path, build((2, 3), group=_set(3, "i64", -2, (1,))), "row count -2")
    refused(tmp_path, build((2, 3), meta=_set(3, "i64", 9)), "hold 5 rows, the footer says 9")
    refused(tmp_path, build((2, 3), meta=_set(3, "i64", -5)), "row count -5")


def test_a_chunk_in_another_file_is_refused(tmp_path):
    def elsewhere(fields, g):
        chunks = fields[1][1][1]
        chunks[0][1] = ("bin", "other.parquet")
    refused(tmp_path, build(group=elsewhere), "in another file")


def test_a_schema_that_does_not_fit_its_row_groups_is_refused(tmp_path):
    def fewer(fields):
        fields[2][1][1][0][5] = ("i32", 2)
    refused(tmp_path, build(meta=fewer), "outside its tree")

    def more(fields):
        fields[2][1][1][0][5] = ("i32", 1 << 30)
    refused(tmp_path, build(meta=more), "fewer elements than its groups claim")

    def columns(fields):
        schema = fields[2][1][1]
        schema[0][5] = ("i32", 4)
        schema.append(dict(schema[-1]))
    refused(tmp_path, build(meta=columns), "3 column chunks for 4 columns")


def test_footer_lies_are_refused(tmp_path):
    good = build()
    refused(tmp_path, good[:-8] + struct.pack("<I", 1 << 31) + b"PAR1", "footer of 2147483648")
    refused(tmp_path, good[:-8] + struct.pack("<I", len(good) - 11) + b"PAR1", "a footer of")
    refused(tmp_path, good[:-4] + b"PARE", "encrypted")
    refused(tmp_path, good[:-1], "does not end with PAR1")
    refused(tmp_path, b"PAR1PAR1", "8 bytes, too short")
    refused(tmp_path, b"PAR1\x00\x00\x00\x00PAR1", "the footer does not decode: truncated")
    # the footer cut short, its length telling the truth
    refused(tmp_path, build(footer=lambda f: f[:len(f) // 2]), "the footer does not decode")
    # the footer's length one byte short: it is read from its second byte on (it decodes, to a
    # struct without the row count)
    refused(tmp_path, good[:-8] + struct.pack("<I", struct.unpack("<I", good[-8:-4])[0] - 1)
            + b"PAR1", "the row count missing")


def test_a_footer_nested_deep_is_refused_without_recursion(tmp_path):
    # a struct in a struct ... 100 000 deep: the decoder stops at its depth limit
    deep = b"\x0c" * 100_000
    refused(tmp_path, build(footer=lambda f: f[:-1] + b"\x7c" + deep), "nested too deep")


def test_a_list_longer_than_its_bytes_is_refused(tmp_path):
    # key_value_metadata (field 5): a list that claims 2**40 entries
    refused(tmp_path, build(footer=lambda f: f[:-1] + b"\x59\xf1" + bytes([0x80] * 5) + b"\x20"
                            + b"\x00"), "a list longer than its bytes")


def test_a_real_file_cut_anywhere_in_its_footer_is_refused(tmp_path):
    path = str(tmp_path / "p.parquet")
    _frame(50).write_parquet(path, compression="zstd")
    data = open(path, "rb").read()
    length = struct.unpack("<I", data[-8:-4])[0]
    start = len(data) - 8 - length
    for cut in range(start + 1, len(data) - 8, max(1, length // 40)):
        # the tail put back as if the footer ended there
        damaged = data[:cut] + struct.pack("<I", cut - start) + b"PAR1"
        with pytest.raises(ValueError):
            check_parquet(write(tmp_path, damaged, "cut.parquet"))

"""The containers' readers: CSV as people write it, .npz and HDF5 held to their own bytes."""

from __future__ import annotations

import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest
from scotti.importers import tables
from scotti.importers.errors import QUOTE_CHARS, InputError
from scotti.importers.tables import load_arrays, read_csv


def csv(tmp_path: Path, data: bytes) -> Path:
    path = tmp_path / "t.csv"
    path.write_bytes(data)
    return path


def error(path: Path) -> str:
    with pytest.raises(InputError) as caught:
        read_csv(path)
    message = str(caught.value)
    assert "\n" not in message
    return message


# --- CSV ----------------------------------------------------------------------------------


def test_comment_and_blank_lines_are_skipped_and_lines_keep_their_numbers(
    tmp_path: Path,
) -> None:
    path = csv(tmp_path, b"# made by a logger\n\nt,a,b\n# a note\n1,2,3\n\n  \n4,5,6\n")
    table = read_csv(path)
    assert table.header == ["t", "a", "b"]
    assert table.header_line == 3
    assert table.values.tolist() == [[1, 2, 3], [4, 5, 6]]
    assert table.lines.tolist() == [5, 8]


@pytest.mark.parametrize("delimiter", [b"\t", b";"])
def test_tab_and_semicolon_delimiters_are_found(tmp_path: Path, delimiter: bytes) -> None:
    body = b"\n".join(delimiter.join(row) for row in [[b"t", b"a"], [b"1", b"2"], [b"3", b"4"]])
    table = read_csv(csv(tmp_path, body + b"\n"))
    assert table.header == ["t", "a"]
    assert table.values.tolist() == [[1, 2], [3, 4]]
    no_header = read_csv(csv(tmp_path, body.split(b"\n", 1)[1]))
    assert no_header.header is None
    assert no_header.values.shape == (2, 2)


def test_a_trailing_delimiter_is_an_empty_last_column_not_a_column(tmp_path: Path) -> None:
    table = read_csv(csv(tmp_path, b"t,a,\n1,2,\n3,4,\n"))
    assert table.header == ["t", "a"]
    assert table.values.tolist() == [[1, 2], [3, 4]]
    crlf = read_csv(csv(tmp_path, b"1;2;\r\n3;4;\r\n5;6;"))
    assert crlf.values.tolist() == [[1, 2], [3, 4], [5, 6]]


def test_bom_and_crlf_line_ends(tmp_path: Path) -> None:
    table = read_csv(csv(tmp_path, b"\xef\xbb\xbft,a\r\n1,2\r\n3,4"))
    assert table.header == ["t", "a"]
    assert table.values.tolist() == [[1, 2], [3, 4]]


def test_an_error_quotes_at_most_a_short_piece_of_a_long_row(tmp_path: Path) -> None:
    row = ",".join(["1.25"] * 300) + ",oops" + "9" * 2000
    path = csv(tmp_path, f"{','.join(f'c{i}' for i in range(301))}\n{row}\n".encode())
    message = error(path)
    assert "line 2, column 301 (c300): 'oops999" in message
    assert "..." in message
    assert len(message) < len(str(path)) + QUOTE_CHARS + 60


def test_wrong_column_count_names_the_line(tmp_path: Path) -> None:
    message = error(csv(tmp_path, b"t,a\n1,2\n3,4,5\n"))
    assert message.endswith("t.csv line 3: 3 columns, expected 2")


@pytest.mark.parametrize(
    ("cell", "problem"),
    [
        (b"x", "'x' is not a number"),
        (b"", "an empty cell"),
        (b"1_0", "'1_0' is not a number"),  # Python's float takes it; numpy does not
        (b"\xdf", "'\ufffd' is not a number"),  # not UTF-8: shown, not a traceback
        (b"4#x", "'4#x' is not a number"),
    ],
)
def test_a_bad_cell_is_named_by_line_and_column(tmp_path: Path, cell: bytes, problem: str) -> None:
    message = error(csv(tmp_path, b"t,a\n1,2\n3," + cell + b"\n"))
    assert f"t.csv line 3, column 2 (a): {problem}" in message


def test_a_decimal_comma_gets_a_hint(tmp_path: Path) -> None:
    message = error(csv(tmp_path, b"t;a\n1,5;2,5\n"))
    assert "line 2, column 1 (t): '1,5' is not a number (a decimal comma" in message


def test_nan_and_inf_are_read_for_the_caller_to_judge(tmp_path: Path) -> None:
    table = read_csv(csv(tmp_path, b"1,nan\n2,inf\n"))
    assert np.isnan(table.values[0, 1])
    assert np.isinf(table.values[1, 1])


def test_a_mistake_deep_in_a_big_file_names_its_line(tmp_path: Path) -> None:
    rows = 3 * tables.BLOCK_BYTES // 12  # some blocks' worth of lines
    body = b"".join(b"%d,%d.5\n" % (i, i) for i in range(rows))
    path = csv(tmp_path, b"# comment\nt,a\n" + body + b"7,x\n" + body[:100])
    assert f"line {rows + 3}, column 2 (a): 'x' is not a number" in error(path)
    path.write_bytes(b"t,a\n" + body)
    table = read_csv(path)
    assert table.values.shape == (rows, 2)
    assert table.lines[-1] == rows + 1
    assert table.values[-1].tolist() == [rows - 1, rows - 0.5]


@pytest.mark.parametrize(
    ("data", "problem"),
    [
        (b"", "t.csv: the file is empty"),
        (b"# only\n\n", "t.csv: the file is empty"),
        (b"t,a\n", "t.csv: no data lines after the header"),
        (b"t,Fu\xdf\n1,2\n", "t.csv line 1: not UTF-8 text"),
        (b"1,2\r3,4\r", "t.csv line 1: lines end in a bare carriage return"),
    ],
)
def test_files_without_a_table(tmp_path: Path, data: bytes, problem: str) -> None:
    assert problem in error(csv(tmp_path, data))


def test_a_line_longer_than_any_frame_is_refused_before_it_is_read_whole(
    tmp_path: Path,
) -> None:
    path = csv(tmp_path, b"t,a\n1,2\n" + b"3" * (tables.MAX_LINE_BYTES + tables.BLOCK_BYTES))
    assert "t.csv from byte " in error(path)
    assert "a line longer than" in error(path)


def test_the_values_match_numpy_s_own_reading(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    body = rng.normal(0, 1e3, (4000, 7))
    path = tmp_path / "n.csv"
    np.savetxt(path, body, delimiter=",", fmt="%.6g", header="a,b,c,d,e,f,g", comments="")
    table = read_csv(path)
    assert np.array_equal(table.values, np.loadtxt(path, delimiter=",", skiprows=1))
    assert table.lines.tolist() == list(range(2, 4002))


def test_a_narrow_read_keeps_float32_and_its_wide_columns_whole(tmp_path: Path) -> None:
    """Pressure tables are read narrow: half the memory, the time stamps kept in float64."""
    rows = 3 * tables.BLOCK_BYTES // 30  # some blocks' worth of lines
    t = 1e9 + np.arange(rows) * 1e-3  # ns-scale stamps float32 cannot tell apart
    body = b"".join(b"%.3f,%d.25,nan\n" % (s, i) for i, s in enumerate(t))
    path = csv(tmp_path, b"t,a,b\n" + body + b"1e300,2,3\n")
    table = read_csv(path, narrow=True, wide=("t", 2))
    assert table.values.dtype == np.float32
    assert set(table.wide) == {0, 2}
    np.testing.assert_array_equal(table.wide[0][:-1], np.round(t, 3))
    assert table.wide[0][-1] == 1e300  # whole in its own column; the float32 copy held in range
    assert table.values[-1, 0] == np.float32(tables.FLOAT32_MAX)
    assert table.values[:-1, 1].tolist() == [i + 0.25 for i in range(rows)]
    assert np.isnan(table.wide[2][0])  # NaN is kept, for the caller to judge
    assert np.isnan(table.values[0, 2])
    path.write_bytes(b"t,a\n" + b"1,2\n" * 5 + b"2,1e39\n")
    with pytest.raises(InputError, match=r"line 7, column 2 \(a\): value 1e\+39 too large"):
        read_csv(path, narrow=True, wide=("t",))
    with pytest.raises(InputError, match=r"no column named 'x'"):
        read_csv(path, narrow=True, wide=("x",))


# --- .npz and HDF5 --------------------------------------------------------------------------


def npz_member(path: Path, name: str, header: dict[str, object], data: bytes) -> None:
    """An .npz whose member ``name`` has this header and these bytes, whatever they say."""
    with zipfile.ZipFile(path, "a", zipfile.ZIP_DEFLATED) as z, z.open(f"{name}.npy", "w") as f:
        np.lib.format.write_array_header_1_0(f, header)
        f.write(data)


def arrays_error(path: Path, keys: list[str]) -> str:
    with pytest.raises(InputError) as caught:
        load_arrays(path, keys)
    assert "\n" not in str(caught.value)
    return str(caught.value)


def test_npz_arrays_read_as_numpy_writes_them(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    fortran = np.asfortranarray(np.arange(24.0).reshape(4, 6))
    np.savez_compressed(path, t=np.arange(5), f=fortran, names=np.array(["a", "bc"]))
    got = load_arrays(path, ["t", "f", "names", "absent?"])
    assert got["t"].tolist() == list(range(5))
    assert np.array_equal(got["f"], fortran)
    assert got["names"].tolist() == ["a", "bc"]
    assert "absent" not in got


def test_an_npz_member_that_declares_more_than_it_holds(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    header = {"descr": "<f8", "fortran_order": False, "shape": (10**9,)}
    npz_member(path, "t", header, bytes(800))
    message = arrays_error(path, ["t"])
    assert "a.npz t: declares (1000000000) float64 (8 GB) but the zip holds 800 bytes" in message


def test_an_npz_member_that_inflates_past_the_budget(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    n = 40_000_000  # 320 MB of zeros, deflated to about 300 kB
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z, z.open("t.npy", "w") as f:
        np.lib.format.write_array_header_1_0(
            f, {"descr": "<f8", "fortran_order": False, "shape": (n,)}
        )
        for _ in range(n // 1_000_000):
            f.write(bytes(8_000_000))
    assert path.stat().st_size < 1_000_000
    message = arrays_error(path, ["t"])
    assert "a.npz t: (40000000) float64 needs 320 MB, more than a file of" in message
    assert "SCOTTI_IMPORT_MAX_BYTES raises it" in message


def test_npz_members_that_are_not_numbers(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    np.savez(path, o=np.array([{"a": 1}], dtype=object), c=np.ones(2, dtype=complex))
    assert "a.npz o: holds object values, not numbers or text" in arrays_error(path, ["o"])
    assert "a.npz c: holds complex128 values" in arrays_error(path, ["c"])
    (tmp_path / "b.npz").write_bytes(b"PK\x03\x04 garbage")
    assert "b.npz: not a readable .npz (BadZipFile)" in arrays_error(tmp_path / "b.npz", ["t"])


def test_a_cut_npz_member(tmp_path: Path) -> None:
    path = tmp_path / "a.npz"
    np.savez(path, t=np.arange(1000.0))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert "a.npz" in arrays_error(path, ["t"])


def test_an_hdf5_dataset_that_declares_samples_the_file_does_not_store(
    tmp_path: Path,
) -> None:
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("contiguous", shape=(10**9,), dtype="f8")
        f.create_dataset("chunked", shape=(10**9,), dtype="f8", chunks=(1024,))
        f["good"] = np.arange(6.0).reshape(2, 3)
    assert path.stat().st_size < 10_000
    message = arrays_error(path, ["good", "contiguous"])
    assert "a.h5 contiguous: declares (1000000000) float64 (8 GB) but the file stores 0" in message
    assert "a.h5 chunked: declares" in arrays_error(path, ["chunked"])
    assert load_arrays(path, ["good"])["good"].tolist() == [[0, 1, 2], [3, 4, 5]]


def test_a_compressed_hdf5_dataset_past_the_budget(tmp_path: Path) -> None:
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as f:  # 320 MB of zeros, gzipped a chunk at a time
        d = f.create_dataset(
            "t", shape=(40_000_000,), dtype="f8", chunks=(1_000_000,), compression="gzip"
        )
        for i in range(40):
            d[i * 1_000_000 : (i + 1) * 1_000_000] = 0.0
    assert path.stat().st_size < 2_000_000
    assert "a.h5 t: (40000000) float64 needs 320 MB, more than a file of" in arrays_error(
        path, ["t"]
    )


def test_hdf5_names_and_strings(tmp_path: Path) -> None:
    path = tmp_path / "a.h5"
    with h5py.File(path, "w") as f:
        f["names"] = ["nose", "left_hip"]
        f["grp/t"] = np.arange(3)
    got = load_arrays(path, ["names", "grp/t"])
    assert list(got["names"]) == ["nose", "left_hip"]
    assert got["grp/t"].tolist() == [0, 1, 2]
    assert "a.h5: no array 'x' (it has: grp/t, names)" in arrays_error(path, ["x"])
    (tmp_path / "b.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    assert "b.h5: not a readable HDF5 file" in arrays_error(tmp_path / "b.h5", ["t"])


def test_values_past_float32_s_range_are_bad_and_float16_is_not_compared_past_its_own() -> None:
    assert tables.first_bad(np.array([[1.0, 2.0], [3.0, 1e300]])) == (1, 1)
    assert "value 1e+300 too large" in tables.describe_value(1e300)
    half = np.array([1.0, 65504.0], dtype=np.float16)  # float16's largest: fine
    assert tables.first_bad(half) is None
    assert tables.first_bad(np.array([1.0, np.inf], dtype=np.float16)) == (1,)


def test_the_fuzzer_s_npz_findings_stay_fixed(tmp_path: Path) -> None:
    """Zero-size values numpy would allocate a byte each for; a header numpy's tokenizer
    chokes on; a zip version zipfile refuses: each one line, none a traceback."""
    path = tmp_path / "a.npz"
    npz_member(path, "t", {"descr": "|S0", "fortran_order": True, "shape": (10**9, 2)}, b"")
    assert "a.npz t: holds values of no size" in arrays_error(path, ["t"])
    path.unlink()
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("t.npy", b"\x93NUMPY\x01\x00\x20\x00{'descr': '<f8', 'shape': (10,\n" + bytes(8))
    assert "a.npz t: not a readable array" in arrays_error(path, ["t"])
    np.savez(path, t=np.arange(3))
    data = bytearray(path.read_bytes())
    central = data.find(b"PK\x01\x02")
    data[central + 6 : central + 8] = (221).to_bytes(2, "little")  # "version needed": 22.1
    path.write_bytes(bytes(data))
    assert "a.npz: not a readable .npz (NotImplementedError)" in arrays_error(path, ["t"])


def test_the_long_fuzz_run_s_findings_stay_fixed(tmp_path: Path) -> None:
    """An entry with no name (zipfile's is_dir: IndexError); a header Python 2 wrote (numpy
    warns, and reads it); an HDF5 name that is not UTF-8 (h5py gives bytes)."""
    path = tmp_path / "a.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr(zipfile.ZipInfo(""), b"")
        z.writestr("t.npy", b"")
    assert "a.npz: no array 'x' (it has: t)" in arrays_error(path, ["x"])
    path.unlink()
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (2L,), }"
    header += b" " * (117 - len(header)) + b"\n"  # 10 + 118 bytes: a multiple of 64
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("t.npy", b"\x93NUMPY\x01\x00v\x00" + header + np.arange(2.0).tobytes())
    assert load_arrays(path, ["t"])["t"].tolist() == [0.0, 1.0]
    h5 = tmp_path / "a.h5"
    with h5py.File(h5, "w") as f:
        f[b"t\xafme"] = np.arange(3)
    assert "a.h5: no array 'time' (it has: t\xafme)" in arrays_error(h5, ["time"])

"""An ESRI (or GRASS) ASCII grid whose header does not match its values: GDAL reads the first nrows x ncols values
in stream order and ignores the rest, so a header declaring too few rows read the grid truncated (and placed by
its lower-left corner, too low), and one declaring too few columns read every row shifted, without a word.
load_dem counts the values and the values a line (a clean grid of another width is refused), and refuses the file
naming what its header declares and what it holds; values wrapped across rows at a fixed width read, as GDAL reads
them. A header GDAL takes for data (its lines indented, a byte-order mark) is named too."""

from __future__ import annotations

import gzip
import zipfile

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import DataFileError

pytest.importorskip("rasterio")


def _header(nrows: int, ncols: int) -> str:
    return f"ncols {ncols}\nnrows {nrows}\nxllcorner 100\nyllcorner 200\ncellsize 10\nNODATA_value -9999\n"


_ROWS = "1 2 3\n4 5 6\n7 8 9\n"


@pytest.mark.parametrize("gzipped", [False, True])
def test_header_declaring_fewer_rows_is_refused(tmp_path, gzipped):
    """nrows 2 over 3 rows: GDAL read the top two, placed a row too low."""
    text = (_header(2, 3) + _ROWS).encode()
    path = tmp_path / ("rows dem.asc.gz" if gzipped else "rows dem.asc")
    path.write_bytes(gzip.compress(text) if gzipped else text)
    pattern = r"rows dem\.asc.*2 x 3 = 6 values \(nrows 2, ncols 3.*got 9 values \(3 rows of 3\)"
    with pytest.raises(DataFileError, match=pattern):
        st.load_dem(path)
    with pytest.raises(DataFileError, match=pattern):  # a crop is placed from the same header
        st.load_dem(path, crop=(100.0, 115.0, 200.0, 215.0))


def test_header_declaring_fewer_columns_is_refused(tmp_path):
    """ncols 2 over rows of 3: GDAL read [[1, 2], [3, 4]] (the rows shifted); every line holds 3 values."""
    path = tmp_path / "dem.asc"
    path.write_text(_header(2, 2) + "1 2 3\n4 5 6\n")
    pattern = r"dem\.asc.*2 x 2 = 4 values \(nrows 2, ncols 2.*got 6 values \(3 rows of 2\)"
    with pytest.raises(DataFileError, match=pattern):
        st.load_dem(path)


@pytest.mark.parametrize(("nrows", "ncols", "body", "held"), [
    (3, 2, "1 2 3\n4 5 6\n", "got 2 lines of 3 values each"),  # 2 x 3 declared 3 x 2: as many values
    (3, 4, "1 2 3\n4 5 6\n7 8 9\n10 11 12\n", "got 4 lines of 3 values each"),  # 4 x 3 declared 3 x 4
])
def test_header_with_rows_and_columns_swapped_is_refused(tmp_path, nrows, ncols, body, held):
    """As many values as declared, but every line holds another count: the rows are not ncols long."""
    path = tmp_path / "dem.asc"
    path.write_text(_header(nrows, ncols) + body)
    with pytest.raises(DataFileError, match=rf"rows of {ncols} values \(nrows {nrows}, ncols {ncols}.*{held}"):
        st.load_dem(path)
    with pytest.raises(DataFileError, match=held):
        st.load_dem(path, crop=(100.0, 120.0, 200.0, 230.0))


@pytest.mark.parametrize("body", ["1 2 3\n4 5 6\n7 8 9\n", "1 2 3 4 5 6 7 8 9\n", "1 2\n3\n4\n5 6\n7 8 9",
                                  "1 2 3 4 5 6\n7 8 9\n\n\n", "\n\n1 2 3\r\n  4 5 6\r\n7\t8\t9\r\n"])
def test_values_matching_the_header_read(tmp_path, body):
    """A row a line, the whole grid on one line, rows wrapped over lines, whole rows a line, blank and indented data
    lines: as GDAL reads them."""
    path = tmp_path / "dem.asc"
    path.write_text(_header(3, 3) + body)
    np.testing.assert_array_equal(st.load_dem(path).heights, np.arange(1, 10, dtype=np.float32).reshape(3, 3))


@pytest.mark.parametrize("gzipped", [False, True])
@pytest.mark.parametrize("width", [10, 5, 3, 14, 28])
def test_values_wrapped_across_rows_read_as_gdal_reads_them(tmp_path, width, gzipped):
    """ESRI's format needs no line break at a row's end: a 4 x 7 grid written 10 (5, 3) values a line across the
    rows (its last line shorter), two rows a line or all on one line, reads in stream order, as GDAL reads it."""
    import rasterio

    heights = np.arange(1, 29, dtype=np.float32).reshape(4, 7)
    flat = heights.ravel()
    body = "\n".join(" ".join(f"{v:g}" for v in flat[i:i + width]) for i in range(0, flat.size, width)) + "\n"
    text = (_header(4, 7) + body).encode()
    path = tmp_path / ("dem.asc.gz" if gzipped else "dem.asc")
    path.write_bytes(gzip.compress(text) if gzipped else text)
    with rasterio.open(f"/vsigzip/{path}" if gzipped else path) as source:
        np.testing.assert_array_equal(source.read(1), heights)  # GDAL's own reading
    np.testing.assert_array_equal(st.load_dem(path).heights, heights)


def test_values_wrapped_at_a_width_making_a_clean_grid_are_refused(tmp_path):
    """4 x 7 values written 4 a line: 7 lines of 4, a 7 x 4 grid with its rows and columns swapped in the header as
    far as any reader can tell, refused (write one row a line)."""
    flat = np.arange(1, 29)
    body = "\n".join(" ".join(map(str, flat[i:i + 4])) for i in range(0, 28, 4)) + "\n"
    path = tmp_path / "dem.asc"
    path.write_text(_header(4, 7) + body)
    with pytest.raises(DataFileError, match=r"rows of 7 values \(nrows 4, ncols 7.*got 7 lines of 4 values each"):
        st.load_dem(path)


def test_clean_grid_of_another_width_told_past_the_lines_looked_at(tmp_path, monkeypatch):
    """Past the first lines looked at (a MiB; here 30 bytes), lines of k values are a grid k wide where k divides the
    values' count: rows and columns swapped are refused; 10 a line across 28 values (a shorter last line) read."""
    import stepterrain.io as io

    monkeypatch.setattr(io, "_ASC_FIRST_ROW", 30)
    path = tmp_path / "dem.asc"
    path.write_text(_header(3, 5) + "1 2 3\n4 5 6\n7 8 9\n10 11 12\n13 14 15\n")  # 5 x 3 declared 3 x 5: 35 bytes
    with pytest.raises(DataFileError, match=r"rows of 5 values \(nrows 3, ncols 5.*got 5 lines of 3 values each"):
        st.load_dem(path)
    flat = np.arange(1, 29)
    path.write_text(_header(4, 7) + "\n".join(" ".join(map(str, flat[i:i + 10])) for i in range(0, 28, 10)))
    np.testing.assert_array_equal(st.load_dem(path).heights, flat.reshape(4, 7).astype(np.float32))


@pytest.mark.parametrize("end", ["\x1a", "\x00\x00\x00", "\n\x1a\n"])
def test_end_of_file_mark_or_padding_is_no_value(tmp_path, end):
    """A DOS end-of-file mark (Ctrl-Z) or NUL padding after the values, which GDAL reads past, is no extra value."""
    path = tmp_path / "dem.asc"
    path.write_bytes((_header(3, 3) + _ROWS + end).encode())
    np.testing.assert_array_equal(st.load_dem(path).heights, np.arange(1, 10, dtype=np.float32).reshape(3, 3))


def test_header_with_a_blank_and_an_unknown_line_reads(tmp_path):
    """GDAL's header ends at the first line not starting with a letter: a blank line or one it does not know
    inside it are header, not values."""
    path = tmp_path / "dem.asc"
    path.write_text("ncols 3\nnrows 3\n\nxllcorner 100\nyllcorner 200\nproducer x\ncellsize 10\n" + _ROWS)
    np.testing.assert_array_equal(st.load_dem(path).heights, np.arange(1, 10, dtype=np.float32).reshape(3, 3))


def test_grass_header_declaring_fewer_rows_is_refused(tmp_path):
    header = "north: 4000020\nsouth: 4000000\neast: 500030\nwest: 500000\nrows: 2\ncols: 3\n"
    path = tmp_path / "grass.asc"
    path.write_text(header + _ROWS)
    with pytest.raises(DataFileError, match=r"a GRASS ASCII grid of 2 x 3 = 6 values \(rows 2, cols 3.*got 9"):
        st.load_dem(path)


@pytest.mark.parametrize("braces", [False, True])
def test_zipped_grid_checked_by_its_vsizip_path(tmp_path, braces):
    """A local zip's member named by /vsizip/ with or without GDAL's braces round the archive."""
    archive = tmp_path / "grids.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zipped:
        zipped.writestr("sub/rows.asc", _header(2, 3) + _ROWS)
        zipped.writestr("sub/short.asc", _header(3, 3) + "1 2 3\n4 5 6\n7 8\n")
    prefix = f"/vsizip/{{{archive}}}" if braces else f"/vsizip/{archive}"
    with pytest.raises(DataFileError, match=r"2 x 3 = 6 values.*got 9"):
        st.load_dem(f"{prefix}/sub/rows.asc")
    with pytest.raises(DataFileError, match=r"3 x 3 = 9 values.*got 8 \(cut short"):
        st.load_dem(f"{prefix}/sub/short.asc")


@pytest.mark.parametrize(("prefix", "said"), [
    ("\ufeff", "a UTF-8 byte-order mark"),
    (" ", "spaces"),
    ("\n", "a blank line"),
])
def test_header_start_gdal_refuses_is_named(tmp_path, prefix, said):
    """GDAL knows an ESRI ASCII grid by its first keyword at the very start of the file: after a byte-order mark,
    spaces or a blank line it said only 'not recognized as being in a supported file format'."""
    path = tmp_path / "bom dem.asc"
    path.write_text(prefix + _header(3, 3) + _ROWS, encoding="utf-8")
    with pytest.raises(DataFileError, match=rf"bom dem\.asc.*starts with {said}"):
        st.load_dem(path)


@pytest.mark.parametrize("zipped", [False, True])
def test_indented_header_line_is_refused(tmp_path, zipped):
    """A header line after the first that starts with a space ends GDAL's header there: the rest of it was read as
    heights ([[0, 2, 0], [100, 0, 200]]: the keywords as 0, their values as heights), without a word."""
    text = "ncols 3\n  nrows 2\n  xllcorner 100\n  yllcorner 200\n  cellsize 10\n1 2 3\n4 5 6\n"
    path = tmp_path / "dem.asc"
    path.write_text(text)
    if zipped:
        with zipfile.ZipFile(tmp_path / "d.zip", "w") as archive:
            archive.writestr("dem.asc", text)
        path = tmp_path / "d.zip"
    with pytest.raises(DataFileError, match=r"dem\.asc.*header line 2 \('  nrows 2'\) starting with spaces"):
        st.load_dem(path)


@pytest.mark.parametrize(("nrows", "ncols", "width"), [(40, 25, 10), (2, 6, 4)])
def test_values_wrapped_evenly_at_a_width_dividing_their_count_read_as_gdal_reads_them(tmp_path, nrows, ncols, width):
    """A 40 x 25 grid written 10 values a line (a Fortran layout: every line full) was refused as "a grid 10 values
    wide" (r136), though GDAL reads it in order: only rows and columns swapped (ncols lines of nrows) is refused."""
    rasterio = pytest.importorskip("rasterio")
    values = np.arange(nrows * ncols, dtype=np.float64).reshape(nrows, ncols) + 1.0
    flat = values.ravel()
    path = tmp_path / "dem.asc"
    path.write_text(_header(nrows, ncols) + "\n".join(" ".join(f"{v:g}" for v in flat[i:i + width])
                                                       for i in range(0, len(flat), width)) + "\n")
    with rasterio.open(path) as source:
        assert np.array_equal(source.read(1), values)
    assert np.array_equal(np.asarray(st.load_dem(path).heights), values)

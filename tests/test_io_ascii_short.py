"""An ESRI ASCII grid cut short by its very last value: GDAL's reader takes the end of the file after the last but
one value as the end of the last one and reads the missing cell as 0 without a word, where any other value missing
is refused ("File short"). load_dem counts the values then, and refuses the file as GDAL refuses the others."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

import stepterrain as st
from stepterrain.errors import DataFileError

pytest.importorskip("rasterio")

_HEADER = "ncols 3\nnrows 3\nxllcorner 100\nyllcorner 200\ncellsize 10\nNODATA_value -9999\n"


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
@pytest.mark.parametrize("gzipped", [False, True])
def test_ascii_grid_missing_its_last_value_is_refused(tmp_path, newline, gzipped):
    text = (_HEADER + "1 2 3\n4 5 6\n7 8\n").replace("\n", newline).encode()
    path = tmp_path / ("cut dem.asc.gz" if gzipped else "cut dem.asc")
    path.write_bytes(gzip.compress(text) if gzipped else text)
    with pytest.raises(DataFileError, match=r"cut dem\.asc.*3 x 3 = 9 values.*got 8 \(cut short"):
        st.load_dem(path)
    with pytest.raises(DataFileError, match=r"got 8 \(cut short"):  # a crop that holds the last cell reads it
        st.load_dem(path, crop=(110.0, 125.0, 200.0, 215.0))
    # a crop away from it reads as GDAL does: the values are there
    assert st.load_dem(path, crop=(100.0, 115.0, 215.0, 230.0)).heights.tolist() == [[1.0, 2.0], [4.0, 5.0]]


@pytest.mark.parametrize("body", ["1 2 3\n4 5 6\n7 8 0\n", "1 2 3\n4 5 6\n7 8 0", "  1 2\t3\n4 5\n6\n7 8 0  \n\n",
                                  "1 2 3 4 5 6 7 8 0\n"])
def test_ascii_grid_whose_last_value_is_0_reads(tmp_path, body):
    """A last value of 0 that is there (with or without a newline after it, rows wrapped over lines, the whole grid
    on one line) is a height of 0. (More values than the header counts, which GDAL ignores, are refused:
    test_io_ascii_header.py.)"""
    path = tmp_path / "dem.asc"
    path.write_text(_HEADER + body)
    np.testing.assert_array_equal(st.load_dem(path).heights, np.array([[1, 2, 3], [4, 5, 6], [7, 8, 0]], np.float32))


def test_classic_mac_line_ends_read_as_gdal_reads_them(tmp_path):
    """Lines ended by a lone \\r (a classic Mac file): GDAL's reader ends a line there, so the header is its six
    lines and a last value of 0 a height; one value missing is refused still."""
    import rasterio

    path = tmp_path / "mac dem.asc"
    path.write_bytes((_HEADER + "1 2 3\n4 5 6\n7 8 0\n").replace("\n", "\r").encode())
    expected = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 0]], np.float32)
    with rasterio.open(path) as source:
        np.testing.assert_array_equal(source.read(1), expected)  # GDAL's own reading
    np.testing.assert_array_equal(st.load_dem(path).heights, expected)
    path.write_bytes((_HEADER + "1 2 3\n4 5 6\n7 8\n").replace("\n", "\r").encode())
    with pytest.raises(DataFileError, match=r"mac dem\.asc.*3 x 3 = 9 values.*got 8 \(cut short"):
        st.load_dem(path)


def test_one_column_grid_starting_with_nan_names_the_line_read_as_header(tmp_path):
    """A one-column grid whose first value is NaN on its own line: GDAL takes the line for a header line (it starts
    with a letter) and reads [2, 3, 0]; the refusal names that line, not a file cut short."""
    import rasterio

    path = tmp_path / "dem.asc"
    path.write_text("ncols 1\nnrows 3\nxllcorner 0\nyllcorner 0\ncellsize 10\nNODATA_value nan\nNaN\n2\n3\n")
    with rasterio.open(path) as source:
        assert source.read(1).ravel().tolist() == [2.0, 3.0, 0.0]  # GDAL's own reading
    with pytest.raises(DataFileError, match=r"3 x 1 = 3 values.*got 2 \(line 7 \('NaN'\) was read as a header line"):
        st.load_dem(path)


def test_ascii_grid_values_counted_across_chunks(tmp_path, monkeypatch):
    """Values are counted in chunks: one cut by a chunk's end is counted once."""
    import stepterrain.io as io

    path = tmp_path / "dem.asc"
    path.write_text(_HEADER + "10 20 30\n40 50 60\n70 80\n")
    # a tiny chunk size: values cut by the chunks' ends
    monkeypatch.setattr(io, "_ASC_CHUNK", 3)
    with pytest.raises(DataFileError, match=r"got 8 \(cut short"):
        st.load_dem(path)
    path.write_text(_HEADER + "10 20 30\n40 50 60\n70 80 0\n")
    assert st.load_dem(path).heights[-1].tolist() == [70.0, 80.0, 0.0]


@pytest.mark.parametrize("local_zip", [True, False])
def test_ascii_grid_in_a_zip_missing_its_last_value_is_refused(tmp_path, local_zip):
    """In a local zip, read as the zip itself or through its ``/vsizip/`` path, as a plain file."""
    import zipfile

    archive = tmp_path / "grids.zip"
    with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as zipped:
        zipped.writestr("dem.asc", _HEADER + "1 2 3\n4 5 6\n7 8\n")
    path = archive if local_zip else f"/vsizip/{archive}/dem.asc"
    with pytest.raises(DataFileError, match=r"3 x 3 = 9 values.*got 8 \(cut short"):
        st.load_dem(path)


def test_grass_ascii_grid_missing_its_last_value_is_refused(tmp_path):
    """A GRASS ASCII grid under an .asc name (GDAL's GRASSASCIIGrid, the same reader) likewise; whole, it reads."""
    header = "north: 4000030\nsouth: 4000000\neast: 500030\nwest: 500000\nrows: 3\ncols: 3\nnull: -9999\n"
    path = tmp_path / "grass.asc"
    path.write_text(header + "1 2 3\n4 5 6\n7 8\n")
    with pytest.raises(DataFileError, match=r"a GRASS ASCII grid of 3 x 3 = 9 values.*got 8 \(cut short"):
        st.load_dem(path)
    path.write_text(header + "1 2 3\n4 5 6\n7 8 0\n")
    assert st.load_dem(path).heights[-1].tolist() == [7.0, 8.0, 0.0]

"""Which cells of a grid are missing, decided once (io.missing_cells) for load_dem and the globe command.

``stepterrain globe``'s .npz INPUT refuses missing cells, naming what marks them; it kept a hand copy of the rules
load_dem applies (the file's nodata compared in the array's own dtype, --nodata values, a boolean mask/valid) in
_cli_globe._load_grid. Both go through io.missing_cells now: the globe refuses exactly the cells load_dem reads as
NaN, for every dtype and marker, and names the markers that mark some cell.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from stepterrain._cli_globe import _load_grid
from stepterrain.errors import InvalidInputError
from stepterrain.io import load_dem, missing_cells

LAT = np.linspace(80.0, -80.0, 9)
LON = np.linspace(-170.0, 170.0, 18)


def _grid(dtype, cells, value):
    z = (np.add.outer(np.arange(9), np.arange(18)) % 7 + 3).astype(dtype)
    for r, c in cells:
        z[r, c] = value
    return z


def _mask(cells):
    mask = np.zeros((9, 18), bool)
    for r, c in cells:
        mask[r, c] = True
    return mask


# (elevation, what beside it in the .npz, --nodata values, the markers the refusal names or None: no refusal)
CASES = [
    (_grid(np.int16, [(2, 3), (7, 1)], -32768), {"nodata": np.int16(-32768)}, (), "nodata -32768"),
    # a float64 nodata rounded to the float32 band's value, as GDAL compares it
    (_grid(np.float32, [(0, 0), (8, 17)], 0.1), {"nodata": np.float64(0.1)}, (), "nodata 0.1"),
    # a fraction no uint8 cell holds marks none; --nodata 5 marks two
    (_grid(np.uint8, [(4, 4), (5, 6)], 5), {"nodata": np.float64(100.01)}, (5.0,), "--nodata 5"),
    # a mask and a valid, NaN cells and a NaN --nodata (which marks nothing)
    (_grid(np.float64, [(1, 1)], np.nan), {"mask": _mask([(3, 3)]), "valid": ~_mask([(6, 9)])}, (-9999.0, np.nan),
     "'mask' or 'valid', NaN or infinite"),
    # --nodata beyond int16 (warned of, no cell) and the file's nodata on none: no refusal
    (_grid(np.int16, [], 0), {"nodata": np.int16(-9999)}, (40000.0,), None),
    # a nodata beyond float32 (inf there: no finite cell); NaN cells are missing anyway
    (_grid(np.float32, [(0, 5)], np.nan), {"nodata": np.float64(1e40)}, (), "NaN or infinite"),
    # the file's nodata and a mask, a --nodata that marks no cell
    (_grid(np.int32, [(2, 2), (2, 4)], -9999), {"nodata": np.int32(-9999), "mask": _mask([(0, 1), (2, 2)])},
     (2.0,), "nodata -9999, 'mask'"),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_the_globe_refuses_exactly_the_cells_load_dem_reads_as_missing(tmp_path, case):
    elevation, beside, given, named = CASES[case]
    path = tmp_path / "grid.npz"
    np.savez(path, elevation=elevation, lat=LAT, lon=LON, **beside)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # an unheld --nodata, a void value: warned of alike by both
        expected = load_dem(path, nodata=list(given) or None).nodata_mask
        try:
            _load_grid(str(path), None, given)
        except InvalidInputError as exc:
            refused = str(exc)
        else:
            refused = None
    if not expected.any():
        assert refused is None, refused
        assert named is None
        return
    assert refused is not None, "the globe took cells load_dem reads as missing"
    found = re.search(r"has (\d+) nodata cells? \((.*); first at row (\d+), column (\d+)\)", refused)
    assert found, refused
    assert int(found[1]) == int(expected.sum()), (refused, int(expected.sum()))
    assert (int(found[3]), int(found[4])) == tuple(np.argwhere(expected)[0]), refused
    if named is not None:
        assert found[2] == named, refused


def test_every_marker_is_named_when_each_marks_a_cell(tmp_path):
    elevation, beside, _, _ = CASES[-1]
    elevation, given = elevation.copy(), (2.0,)
    elevation[5, 5] = 2
    path = tmp_path / "grid.npz"
    np.savez(path, elevation=elevation, lat=LAT, lon=LON, **beside)
    with pytest.raises(InvalidInputError, match=r"has 4 nodata cells \(--nodata 2, nodata -9999, 'mask'; first at "
                                                r"row 0, column 1\)"):
        _load_grid(str(path), None, given)
    marks: list[str] = []
    hits = missing_cells(elevation, -9999.0, given, beside["mask"], marked_by=marks)
    assert marks == ["nodata", "given", "mask"] and int(hits.sum()) == 4
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degrees read as local metres
        assert int(load_dem(path, nodata=list(given)).nodata_mask.sum()) == 4


def test_missing_cells_marks_none_without_a_marker_and_compares_real_dtypes_only():
    z = np.arange(12.0).reshape(3, 4)
    assert missing_cells(z) is None and missing_cells(z, given=(np.nan,)) is None
    marks: list[str] = []
    hits = missing_cells(z, 3.0, (5.0, 1e300), None, marked_by=marks)
    assert marks == ["nodata", "given"] and np.flatnonzero(hits).tolist() == [3, 5]
    mask = np.zeros((3, 4), bool)
    hits = missing_cells(z, missing=mask)
    assert hits is not mask and not hits.any()
    assert missing_cells(np.array([["a", "b"]]), 1.0, (2.0,)) is None

"""Regression tests for bugs found by an adversarial hunt of the globe (paper 003): each fails without its fix."""

from __future__ import annotations

import math
import re
import sys
import warnings

import numpy as np
import pytest
import warp as wp
from stepterrain.kernels import cubesphere as cs

import stepterrain._compaction as compaction
from stepterrain.errors import InvalidInputError, OutputTooLargeError
from stepterrain.globe import EARTH_RADIUS, Camera, Globe, adaptive_mesh, look_from, render_view

from .conftest import budget_counts, needs_render

LAT1 = np.linspace(89.5, -89.5, 180)
LON1 = np.linspace(-179.5, 179.5, 360)


@pytest.fixture
def budget():
    """Set the memory budget for one test, restored afterwards."""
    previous = compaction.get_memory_budget()
    yield compaction.set_memory_budget
    compaction.set_memory_budget(previous)


def test_a_globe_mesh_over_the_memory_budget_is_refused(budget):
    """The full-resolution mesh of a 65² globe holds 49,152 faces (int64, 24 bytes, and the int32 cube face) and
    24,578 vertices (float64, 24 bytes, and the int32 node entry): 2,064,440 bytes. Only each refinement level was
    checked (the largest needs ~1.5 MiB), so a 1.6 MiB budget let the 2 MiB mesh through."""
    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=65, device="cpu")
    budget(1600 << 10)
    with pytest.raises(OutputTooLargeError, match=r"the mesh \(24,578 vertices, up to 49,152 faces\) would need "
                                                  r"3\.7 MiB.*raise the error or narrow the view"):  # + working arrays
        globe.mesh()
    budget(4 << 20)
    assert len(globe.mesh().faces) == 49_152  # within the budget: the same mesh as ever


def test_the_globe_mesh_check_counts_the_arrays_held_beside_the_mesh(budget):
    """The mesh's check counted its own arrays only (float64 vertices and node entries, int64 faces and cube faces:
    28 bytes each), while the leaves of every level, the per-node vertex ids, the keep counts and the level passes'
    scratch are held with them: face_size 1025 at error 0 was checked as 504 MiB and peaked at 1.1 GiB of RSS (2049:
    2.0 GiB checked, 3.7 GiB used), so a budget that let the check through let the process use twice as much. Now
    those arrays are counted (within a few per cent of the measured peak at 513 to 2049)."""
    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=65, device="cpu")
    n_vertices, n_faces = 24_578, 49_152
    own = 28 * (n_vertices + n_faces)  # the mesh's own arrays: what was checked
    budget(own * 3 // 2)
    with pytest.raises(OutputTooLargeError, match=r"^the mesh \(24,578 vertices, up to 49,152 faces\) would need "):
        globe.mesh()
    budget(own * 2)  # the leaves alone add 16 bytes a face, the level scratch another 16
    mesh = globe.mesh()
    assert (len(mesh.vertices), len(mesh.faces)) == (n_vertices, n_faces)


def test_a_planar_mesh_over_the_memory_budget_is_refused(budget):
    """adaptive_mesh at error 0 on a 129² grid: 32,768 faces and 16,641 vertices (1.3 MiB) got through a 1 MiB
    budget that each of its levels fitted."""
    budget(1 << 20)
    with pytest.raises(OutputTooLargeError, match=r"the mesh \(16,641 vertices, up to 32,768 faces\) would need "
                                                  r"2\.7 MiB"):  # 1.3 MiB of mesh, the rest working arrays
        adaptive_mesh(np.zeros((129, 129)), error=0.0, device="cpu")


class _Allocated(Exception):
    pass


def _no_allocation(*args, **kwargs):
    """Stands in for an allocator: validation passed."""
    raise _Allocated


def test_a_face_size_beyond_int32_node_entries_is_refused_by_name(budget, monkeypatch):
    """6 · 32769² node entries (6.4e9) overflow the kernels' int32 entries (and 32768 << 16 the packed corners):
    with a budget raised to hold them, face_size=32769 went on to allocate 200 GB and resample into wrapped
    indices. The largest face size is 16385 (1.6e9 entries)."""
    import stepterrain.globe as globe_module

    monkeypatch.setattr(globe_module, "_node_array", _no_allocation)
    budget(1 << 50)
    with pytest.raises(InvalidInputError, match=r"^face_size must be at most 16385 \(int32 node entries\); "
                                                r"got 32769$"):
        Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=32769, device="cpu")
    with pytest.raises(_Allocated):  # the largest face size passes validation
        Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=16385, device="cpu")


def test_a_planar_grid_beyond_the_packed_corners_is_refused_by_name(budget, monkeypatch):
    """16386 rows pad to 32769² nodes, whose corner row 32768 << 16 does not fit the int32 packed corners: with
    the budget raised, adaptive_mesh padded the grid (4 GB), then crashed with numpy's OverflowError."""

    import stepterrain.globe as globe_module

    monkeypatch.setattr(np, "pad", _no_allocation)
    monkeypatch.setattr(globe_module, "_node_array", _no_allocation)  # the padded heights (in place, not np.pad)
    budget(1 << 50)
    with pytest.raises(InvalidInputError, match=r"^heights must have at most 16385 rows and columns \(padded to "
                                                r"2\^k \+ 1 nodes, int32 packed corners\); got shape \(16386, 2\)$"):
        adaptive_mesh(np.zeros((16386, 2)), error=1.0, device="cpu")
    with pytest.raises(_Allocated):  # the largest grid passes validation
        adaptive_mesh(np.zeros((16385, 2)), error=1.0, device="cpu")


def _guard_allocations(monkeypatch):
    """wp.empty refuses anything over 10M elements (raises _Allocated): a test never allocates gigabytes."""
    import warp as wp

    empty = wp.empty

    def guarded(shape=0, *args, **kwargs):
        if int(np.prod(shape)) > 10_000_000:
            raise _Allocated
        return empty(shape, *args, **kwargs)

    monkeypatch.setattr(wp, "empty", guarded)


def test_a_refinement_level_beyond_int32_counts_is_refused(budget, monkeypatch):
    """A level of 2^31 triangles needs 2^32 + 2 int32 counts and wraps the offsets: with a budget raised to hold
    it (50+ GiB), the level passes went on to allocate its 2^31 children. The count pass of level 2 reports 2^30
    refined triangles here (standing in for a huge view), so level 3 would hold 2^31: refused by name first."""
    import stepterrain.globe as globe_module

    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu")
    monkeypatch.setattr(globe_module, "_SMALL_LEVELS", 0)  # level passes on the CPU too, as on CUDA
    host_int = globe_module._host_int
    calls = []

    def huge_count(array, index):
        calls.append(index)
        return 1 << 30 if len(calls) == 3 else host_int(array, index)

    monkeypatch.setattr(globe_module, "_host_int", huge_count)
    _guard_allocations(monkeypatch)
    budget(1 << 50)
    with pytest.raises(OutputTooLargeError, match=r"^refinement level 3 would hold 2,147,483,648 triangles, over "
                                                  r"the 1,073,741,822 that its counts and offsets \(int32 in the "
                                                  r"kernels\) can index, whatever the memory budget"):
        globe.mesh()


def test_a_mesh_beyond_int32_faces_is_refused(budget, monkeypatch):
    """The mesh's faces get one int32 keep count each and one more: levels that each fit could together hold more
    faces than that. The limit lowered to 700 stands in for 2^31 - 1: the 768 faces of the 9² globe are refused
    (without the check they went on to the face passes)."""
    import stepterrain.globe as globe_module

    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu")
    monkeypatch.setattr(globe_module, "_MAX_INT32", 700, raising=False)
    with pytest.raises(OutputTooLargeError, match=r"^the mesh would hold 768 faces, over the 699 that its face "
                                                  r"counts and offsets \(int32 in the kernels\) can index"):
        globe.mesh()
    monkeypatch.setattr(globe_module, "_MAX_INT32", 769, raising=False)
    assert len(globe.mesh().faces) == 768


def _mountain_globe(face_size=33):
    """A 1° globe: sea at -4000 m, a 6 km Gaussian mountain at (0°, 0°) and a plateau at -1000 m around (0°, 90°E)."""
    lat, lon = np.meshgrid(LAT1, LON1, indexing="ij")
    z = -4000.0 + 10000.0 * np.exp(-(lat**2 + lon**2) / (2 * 8.0**2))
    z = np.where((np.abs(lat) < 15) & (np.abs(lon - 90) < 15), -1000.0, z)
    return Globe.from_latlon(z, LAT1, LON1, face_size=face_size, device="cpu")


def _eye(lat_deg, lon_deg, r):
    la, lo = np.radians(lat_deg), np.radians(lon_deg)
    return (r * np.cos(la) * np.cos(lo), r * np.cos(la) * np.sin(lo), r * np.sin(la))


def _camera(eye):
    return Camera(eye=eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0))


def test_a_camera_inside_a_mountain_is_refused():
    """The eye was only compared with the lowest node (R - 4000 m): an eye 3 km above sea level inside the 6 km
    mountain, or 2 km below sea level inside the -1000 m plateau, passed and meshed the planet from inside. The
    surface in the eye's direction is the bound now; the same eyes where the terrain is lower pass."""
    globe = _mountain_globe()
    R = globe.radius
    with pytest.raises(InvalidInputError, match=r"^camera eye \(6374000\.0, 0\.0, 0\.0\) lies inside the planet, below "
                                                r"the terrain surface in its direction: \|eye\| = 6374000\.0 m, the "
                                                r"surface there 637[5-7]\d{3}\.\d m from the centre \(radius "
                                                r"6371000\.0 m, terrain \+[5-6]\d{3}\.\d m\); raise the eye$"):
        globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 0.0, R + 3000.0)))
    with pytest.raises(InvalidInputError, match=r"inside the planet, below the terrain surface in its direction: "
                                                r"\|eye\| = 6369000\.0 m, the surface there 6370000\.0 m .* terrain "
                                                r"-1000\.0 m\)"):
        globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 90.0, R - 2000.0)))
    # the same heights over the sea: above the surface there
    assert len(globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 180.0, R + 3000.0))).faces) > 0
    assert len(globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 180.0, R - 2000.0))).faces) > 0


@pytest.mark.parametrize("face_size", [5, 33])
def test_the_surface_bound_is_the_node_height_at_a_node(face_size):
    """At the highest node (the mountain's top at (0°, 0°), face 0's centre node) an eye a few metres above the node
    passes and one a few metres below is refused: the bound is the terrain there, not a cell's lowest corner nor its
    highest."""
    globe = _mountain_globe(face_size)
    heights, positions = globe.heights.reshape(-1), globe.positions.reshape(-1, 3).astype(np.float64)
    top = int(np.argmax(heights))
    r = globe.radius + float(heights[top])
    direction = positions[top] / np.linalg.norm(positions[top])
    globe.mesh(error=1000.0, camera=_camera(tuple(direction * (r + 5.0))))
    with pytest.raises(InvalidInputError, match="inside the planet"):
        globe.mesh(error=1000.0, camera=_camera(tuple(direction * (r - 5.0))))


def test_the_cli_names_an_eye_below_the_terrain_by_its_option(tmp_path, capsys):
    """``--eye 28,87,100`` (100 m above the sphere over the Himalaya, whose terrain stands ~2.6 km high on 33² faces)
    is refused by its option; the library's message named only a planet-centred "camera eye" the user never gave.
    With --no-camera (and no --png) the eye is not used: refused as an option that does nothing, and the same run
    without it passes."""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    argv = ["globe", "--face-size", "33", "--eye", "28,87,100", "-o", str(out), "--device", "cpu"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert re.search(r"error: --eye 28,87,100 lies below the terrain there \(the altitude is metres above the sphere "
                     r"of --radius\): camera eye \(.*\) lies inside the planet, below the terrain surface in its "
                     r"direction: \|eye\| = 6371100\.0 m", err), err
    assert not out.exists()
    assert main([*argv, "--no-camera"]) == 2
    assert "error: --eye applies only with the camera or a --png render" in capsys.readouterr().err
    assert not out.exists()
    assert main([*argv[:3], *argv[5:], "--no-camera"]) == 0 and out.exists()


@pytest.mark.parametrize("dtype", [np.int16, np.float32])
def test_the_cli_refuses_nodata_cells_of_a_global_npz_by_name(tmp_path, capsys, dtype):
    """An .npz's ``nodata`` value (as io.load_dem reads it) was ignored by ``stepterrain globe``: its missing
    cells became -32768 m pits in the mesh. They are refused now, naming the file, the count and the first cell;
    the same file without missing cells meshes."""
    from stepterrain.cli import main

    elevation = np.zeros((180, 360), dtype)
    elevation[3, 7] = elevation[100, 200] = -32768
    grid, out = tmp_path / "grid.npz", tmp_path / "g.ply"
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, nodata=np.array(-32768, dtype))
    argv = ["globe", str(grid), "--face-size", "9", "--no-camera", "-o", str(out), "--device", "cpu"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {str(grid)!r}: 'elevation' has 2 nodata cells (nodata -32768; first at row 3, column 7); the " \
           "globe needs a height everywhere" in err, err
    assert not out.exists()
    elevation[elevation == -32768] = 0
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, nodata=np.array(-32768, dtype))
    assert main(argv) == 0 and out.exists()


def test_the_cli_refuses_the_masked_cells_and_the_scale_of_a_global_npz_as_load_dem_reads_them(tmp_path, capsys):
    """``stepterrain globe`` read a global .npz's 'elevation', 'lat', 'lon' and 'nodata' only: a boolean 'mask'
    (np.savez(..., elevation=m.data, mask=m.mask)) or 'valid' beside them was ignored, its cells meshed as their
    stored values (-32768 m pits), and a 'scale'/'offset' too (heights 10 times too high). Masked cells are refused
    now as nodata cells are, naming what marks them, and a scale as load_dem refuses it; a masked array's mask with
    no cell masked (NumPy's 0-d nomask) meshes."""
    from stepterrain.cli import main

    elevation = np.zeros((180, 360), np.int16)
    elevation[3, 7] = elevation[100, 200] = -32768
    grid, out = tmp_path / "grid.npz", tmp_path / "g.ply"
    argv = ["globe", str(grid), "--face-size", "9", "--no-camera", "-o", str(out), "--device", "cpu"]
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, mask=elevation == -32768)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"error: {str(grid)!r}: 'elevation' has 2 nodata cells ('mask'; first at row 3, column 7); the globe " \
           "needs a height everywhere" in err, err
    valid = np.ones(elevation.shape, bool)
    valid[50, 60] = False
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, valid=valid, nodata=np.int16(-32768))
    assert main(argv) == 2
    assert "has 3 nodata cells (nodata -32768, 'valid'; first at row 3, column 7)" in capsys.readouterr().err
    elevation[elevation == -32768] = 0
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, scale_factor=0.1)
    assert main(argv) == 2
    assert "got scale_factor=0.1, a scale of the stored values" in capsys.readouterr().err
    assert not out.exists()
    clean = np.ma.masked_equal(elevation, -32768)  # no cell masked: its mask is a 0-d False
    np.savez(grid, elevation=clean.data, lat=LAT1, lon=LON1, mask=clean.mask)
    assert main(argv) == 0 and out.exists()


def test_the_cli_names_the_npz_input_of_nan_or_infinite_heights(tmp_path, capsys):
    """A global .npz's NaN (or ±inf) heights, nodata as load_dem reads them, were refused by Globe.from_latlon's
    "elevation has 1 NaN or infinite value", naming no INPUT (a raster's NaN nodata names it since a session ago):
    they are counted with the other nodata cells of the file now, naming the file and what marks them."""
    from stepterrain.cli import main

    grid, out = tmp_path / "grid.npz", tmp_path / "g.ply"
    argv = ["globe", str(grid), "--face-size", "9", "--no-camera", "-o", str(out), "--device", "cpu"]
    for void in (np.nan, -np.inf):
        elevation = np.zeros((180, 360), np.float32)
        elevation[3, 7] = void
        np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1)
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"error: {str(grid)!r}: 'elevation' has 1 nodata cell (NaN or infinite; first at row 3, column 7); " \
               "the globe needs a height everywhere" in err, err
        elevation[100, 200] = -9999
        np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, nodata=np.float32(-9999))
        assert main(argv) == 2
        assert "has 2 nodata cells (nodata -9999, NaN or infinite; first at row 3, column 7)" in capsys.readouterr().err
    assert not out.exists()


def test_a_finite_height_beyond_float32_is_named_as_such():
    """A finite float64 height of 1e39 overflowed to inf in the float32 cast (with numpy's RuntimeWarning) and was
    reported as one of the 'NaN or infinite values' to fill, for the globe and the planar mesh alike."""
    z = np.zeros((180, 360))
    z[5, 6] = -1e39
    with pytest.raises(InvalidInputError, match=r"^elevation must fit in float32 \(\|z\| <= 3\.4e\+38 m\); got -1e\+39 "
                                                r"at row 5, column 6$"):
        Globe.from_latlon(z, LAT1, LON1, face_size=5, device="cpu")
    with pytest.raises(InvalidInputError, match=r"^heights must fit in float32 .* got -1e\+39 at row 5, column 6$"):
        adaptive_mesh(z[:9, :9], error=1.0, device="cpu")


def test_a_planar_camera_below_the_terrain_is_refused_by_name():
    """adaptive_mesh had no camera-below-terrain check: an eye under the heightfield (here 50 m under a 300 m
    plateau) was accepted and the distance scale fell back to the grid spacing. It is refused now, like Globe.mesh
    refuses an eye inside the planet; the surface under the eye is interpolated (a ramp: between nodes), the origin
    counts, and an eye beside the grid's rectangle may be low."""
    z = np.add.outer(np.zeros(9), 100.0 * np.arange(9.0)) + 200.0  # x = j·10 + 1000: z = 200 + 10 (x - 1000)
    origin = (1000.0, 2000.0)

    def camera(x, y, height):
        return Camera(eye=(x, y, height), target=(1040.0, 2040.0, 0.0), up=(0.0, 1.0, 0.0), near=0.1)

    with pytest.raises(InvalidInputError, match=r"^camera eye \(1035\.0, 2040\.0, 540\.0\) lies below the terrain "
                                                r"surface: at \(x, y\) = \(1035\.0, 2040\.0\) the surface is at "
                                                r"z = 550\.0 m, the eye at z = 540\.0 m; raise the eye"):
        adaptive_mesh(z, error=1.0, spacing=10.0, origin=origin, camera=camera(1035.0, 2040.0, 540.0), device="cpu")
    with pytest.raises(InvalidInputError, match=r"the surface is at z = 200\.0 m, the eye at z = 150\.0 m"):
        adaptive_mesh(z, error=1.0, spacing=10.0, origin=origin, camera=camera(1000.0, 2080.0, 150.0), device="cpu")
    for eye in [(1035.0, 2040.0, 560.0), (990.0, 2040.0, 0.0), (1035.0, 1990.0, 0.0)]:  # above; beside the grid
        mesh = adaptive_mesh(z, error=1.0, spacing=10.0, origin=origin, camera=camera(*eye), cull=False,
                             device="cpu")
        assert len(mesh.faces) > 0


def test_a_closing_longitude_column_that_differs_from_the_first_is_refused():
    """A node-registered grid's closing column (lon = first + 360) was dropped whatever its values, so a grid whose
    two copies of the same meridian disagreed (here by 250 m at one row) meshed silently from the first copy. It is
    refused now, naming both columns and the largest difference; float rounding (1 mm) still passes, and gives the
    globe of the grid without the closing column."""
    lat = np.linspace(90.0, -90.0, 19)
    lon = np.linspace(-180.0, 180.0, 37)  # node-registered: -180 and 180 are the same meridian
    rng = np.random.default_rng(7)
    z = rng.uniform(-4000.0, 4000.0, (19, 37))
    z[:, -1] = z[:, 0]
    z[:, -1] += rng.uniform(-1e-3, 1e-3, 19)  # rounding: the same meridian
    closed = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    open_grid = Globe.from_latlon(z[:, :-1], lat, lon[:-1], face_size=9, device="cpu")
    np.testing.assert_array_equal(closed.heights, open_grid.heights)
    z[7, -1] = z[7, 0] + 250.0
    z[3, -1] = z[3, 0] - 2.0
    message = (rf"^elevation's closing column \(lon 180\) must repeat its first column \(lon -180\), the same "
               rf"meridian, within 0\.01 m; got 2 rows that differ, by up to 250 m \(at lat 20: "
               rf"{np.float32(z[7, -1]):.9g} m against {np.float32(z[7, 0]):.9g} m\): inconsistent data")
    with pytest.raises(InvalidInputError, match=message):
        Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    with pytest.raises(InvalidInputError, match=r"differ, by up to 250 m \(at lat 20:"):  # either axis reversed
        Globe.from_latlon(z[::-1, ::-1], lat[::-1], lon[::-1], face_size=9, device="cpu")


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--eye", "0,0,1e300"], "--eye altitude must keep the eye within 1e+30 m of the centre; got --radius "
                                 "6.371e+06 + altitude 1e+300 m"),
        (["--radius", "1e35"], "--radius + the --eye altitude must keep the eye within 1e+30 m of the centre; got "
                               "--radius 1e+35 + altitude 3e+35 m (the default --eye, 3 x --radius)"),
        (["--radius", "1e35", "--eye", "0,0,1e31"], "--eye altitude must keep the eye within 1e+30 m of the centre; "
                                                   "got --radius 1e+35 + altitude 1e+31 m"),
    ],
)
def test_an_eye_beyond_the_camera_bound_names_the_options(tmp_path, capsys, argv, message):
    """An --eye altitude of 1e300 m (or a --radius of 1e35 m under the default eye) was reported as the library's
    'radius + altitude must stay within 1e+30 m', which _as_option turned into '--radius + altitude': it blamed
    --radius for the altitude. The CLI checks the bound itself, before loading anything, naming the options."""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    assert main(["-q", "globe", *argv, "--face-size", "9", "-o", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert f"stepterrain globe: error: {message}\n" == err, err
    assert not out.exists()


def test_a_huge_radius_without_the_camera_is_not_refused_for_the_unused_default_eye(tmp_path, capsys):
    """--radius 1e35 --no-camera (no --png): the library takes radii up to 8.5e37 m, and nothing places an eye (the
    mesh is refined by the geometric error alone, nothing is rendered), yet the CLI refused it for the default eye
    3 radii up, beyond the camera's 1e30 m bound ("(the default --eye, 3 x --radius)"). With the camera or a --png
    the eye is needed and still refused (test_an_eye_beyond_the_camera_bound_names_the_options)."""
    import trimesh

    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    assert main(["-q", "globe", "--radius", "1e35", "--no-camera", "--error", "0", "--face-size", "5", "-o", str(out),
                 "--device", "cpu"]) == 0, capsys.readouterr().err
    mesh = trimesh.load(out, process=False)
    assert len(mesh.faces) == 12 * 4**2 and mesh.is_watertight
    np.testing.assert_allclose(np.linalg.norm(mesh.vertices, axis=1), 1e35, rtol=1e-6)
    png = tmp_path / "g.png"  # a render needs the eye: refused, before anything is loaded or written
    assert main(["-q", "globe", "--radius", "1e35", "--no-camera", "--png", str(png), "--face-size", "5"]) == 2
    assert "(the default --eye, 3 x --radius)" in capsys.readouterr().err
    assert not png.exists()


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
@pytest.mark.parametrize("option", ["--exaggeration", "--radius", "--error", "--tilt", "--heading"])
def test_every_float_globe_option_names_itself_for_a_non_finite_value(tmp_path, capsys, option, value):
    """Each float option of ``stepterrain globe`` given inf or nan: the error names the option, not the library's
    argument (a guard: ``heading must be a finite number`` from look_from reaches the user as ``--heading``)."""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    assert main(["-q", "globe", f"{option}={value}", "--face-size", "9", "-o", str(out), "--device", "cpu"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"stepterrain globe: error: {option} must ") and value in err, err
    assert not out.exists()
    for eye in (f"{value},0,100", f"0,{value},100", f"0,0,{value}"):
        assert main(["-q", "globe", f"--eye={eye}", "--face-size", "9", "-o", str(out), "--device", "cpu"]) == 2
        err = capsys.readouterr().err
        assert "error: argument --eye: expected finite numbers" in err, err


# ------------------------------------------------------------------------------------------ fuzzing (h9)
def _small_globe():
    lat, lon = np.arange(-85, 90, 10.0), np.arange(-175, 180, 10.0)
    return Globe.from_latlon(np.zeros((lat.size, lon.size)), lat, lon, face_size=17, device="cpu")


@pytest.mark.parametrize("axis", ["lat", "lon"])
def test_ragged_latitude_or_longitude_axes_are_named(axis):
    """np.asarray of a ragged axis raised numpy's "inhomogeneous shape" ValueError, naming neither axis."""
    axes = {"lat": np.arange(-85, 90, 10.0), "lon": np.arange(-175, 180, 10.0)}
    axes[axis] = [[1.0, 2.0], [3.0]]
    with pytest.raises(InvalidInputError, match=rf"^{axis} must be .*got rows of different lengths"):
        Globe.from_latlon(np.zeros((18, 36)), axes["lat"], axes["lon"], face_size=17, device="cpu")


@pytest.mark.parametrize("options, name", [
    (dict(bounds=np.array(["cone", "sphere"], dtype=object)), "bounds"),
    (dict(metrics=np.array("geometric")), "metrics"),
    (dict(metrics=[np.array(["geometric", "clip"])]), "metrics"),
    (dict(metrics=np.zeros((2, 2))), "metrics"),
])
def test_bounds_and_metrics_given_as_arrays_are_named(options, name):
    """A name compared with an array raised numpy's "truth value of an array is ambiguous" ValueError, and a 0-d
    array of metrics "iteration over a 0-d array" (TypeError)."""
    with pytest.raises(InvalidInputError, match=rf"^{name} must be"):
        _small_globe().mesh(error=100.0, **options)
    if name == "metrics":
        with pytest.raises(InvalidInputError, match=rf"^{name} must be"):
            adaptive_mesh(np.zeros((9, 9)), error=1.0, device="cpu", **options)


@pytest.mark.parametrize("metric", [lambda: 1.0, lambda points: points[:, 0], lambda p, r, extra: r])
def test_a_user_metric_of_the_wrong_arity_is_named(metric):
    """A callable that cannot take (points, bounding_radius) failed at the first level with Python's TypeError."""
    with pytest.raises(InvalidInputError, match=r"a user metric must take two arguments"):
        _small_globe().mesh(error=100.0, metrics=["geometric", metric])


def test_a_user_metric_beyond_float32_refines_without_runtime_warnings():
    """Factors beyond float32 overflowed in the cast with a RuntimeWarning per level (refining as inf does);
    capped at float32's largest they refine alike, silently."""
    globe = _small_globe()
    full = globe.mesh(error=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        huge = globe.mesh(error=1e-3, metrics=["geometric", lambda p, r: np.full(len(p), 1e300)])
        zero_after_huge = globe.mesh(error=1e-3, metrics=[lambda p, r: np.full(len(p), 1e300),
                                                          lambda p, r: np.full(len(p), 1e300),
                                                          lambda p, r: np.zeros(len(p))])
    assert len(huge.faces) == len(full.faces)
    assert len(zero_after_huge.faces) == 12  # a zero metric refines nothing: the cube's twelve triangles


def test_durations_are_no_heights_or_degrees_for_the_globe():
    # numpy counts timedelta64 as an integer type: seconds were taken as heights and as degrees of the axes
    from stepterrain.errors import InvalidInputError
    from stepterrain.globe import Globe

    lat = np.linspace(-80.0, 80.0, 9)
    lon = np.linspace(-180.0, 180.0, 17)[:-1]
    z = np.zeros((9, 16))
    with pytest.raises(InvalidInputError, match="elevation"):
        Globe.from_latlon(z.astype("timedelta64[s]"), lat, lon, face_size=9, device="cpu")
    with pytest.raises(InvalidInputError, match="lat must be numbers"):
        Globe.from_latlon(z, lat.astype(int).astype("timedelta64[s]"), lon, face_size=9, device="cpu")
    Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")  # the same grid in numbers is taken


@pytest.mark.parametrize("longitude", [1e300, -361.0, 720.0])
def test_a_longitude_beyond_one_turn_either_way_is_refused(longitude):
    # any finite longitude was taken: 1e300 degrees put the camera in a direction of no meaning
    from stepterrain.errors import InvalidInputError
    from stepterrain.globe import look_from

    with pytest.raises(InvalidInputError, match=r"longitude must lie in \[-360, 360\] degrees"):
        look_from(10.0, longitude, 1e6)
    assert np.allclose(look_from(10.0, 350.0, 1e6).eye, look_from(10.0, -10.0, 1e6).eye)


def test_look_from_takes_whole_turns_off_the_heading_and_bounds_the_tilt():
    """look_from took tilt=1e308 (a view of no meaning: radians(1e308) kept none of the angle) and turned heading=1e308
    by whatever cos(1.7e306) gave. The heading is now reduced modulo 360 exactly before it becomes radians, and a tilt
    outside [-90, 90] degrees (from straight down to the horizon) is refused by name."""
    from stepterrain.globe import look_from

    far = look_from(46.0, 9.0, 4e5, tilt=30.0, heading=1e308)
    near = look_from(46.0, 9.0, 4e5, tilt=30.0, heading=math.fmod(1e308, 360.0))
    assert far == near
    assert look_from(46.0, 9.0, 4e5, tilt=30.0, heading=-330.0) == look_from(46.0, 9.0, 4e5, tilt=30.0, heading=-330.0)
    for tilt in (1e308, 90.5, -91.0):
        with pytest.raises(InvalidInputError, match=r"^tilt must lie in \[-90, 90\] degrees from straight down; got "):
            look_from(46.0, 9.0, 4e5, tilt=tilt)
    look_from(46.0, 9.0, 4e5, tilt=90.0)  # the horizon: the bound itself is taken


def _nadir_kept(globe, camera):
    """Whether the culled view keeps the vertex of the unculled view nearest the ground under the eye."""
    direction = np.asarray(camera.eye) / np.linalg.norm(camera.eye)
    whole = globe.mesh(error=0.0, camera=camera, cull=False)
    nadir = np.asarray(whole.vertices)[np.argmax(np.asarray(whole.vertices) @ direction)]
    culled = np.asarray(globe.mesh(error=0.0, camera=camera).vertices)
    return bool(np.isclose(culled, nadir, rtol=0, atol=1e-9 * globe.radius).all(axis=1).any())


def test_look_from_over_a_small_planet_does_not_clip_the_ground_under_the_eye():
    """look_from's near plane lay at least 1 m from the eye whatever the radius: over a planet of radius 1 at
    altitude 0.5 the clip metric culled the whole ground in front of the eye, and the view kept only the far side
    of the planet (nearest vertex at cos -0.2 from the nadir). It now lies at a thousandth of the eye's height
    above the highest surface, at least min(1 m, 1e-6 · radius)."""
    from stepterrain.globe import look_from

    globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, radius=1.0, device="cpu")
    camera = look_from(10.0, 20.0, 0.5, radius=1.0)
    assert 0.0 < camera.near < 0.5  # nearer than the ground
    assert _nadir_kept(globe, camera)


def test_look_from_puts_the_near_plane_before_the_highest_surface():
    """With max_radius (the highest exaggerated surface) given, the near plane still lay at a thousandth of the
    altitude above the sphere: 100 m for an eye 20 m above a 100 km (exaggerated) summit, which the clip metric
    then treats as in front of the view (a finer mesh loses the summit under the eye). The near plane now lies
    nearer than any surface point: at a thousandth of the eye's height above the sphere of max_radius."""
    from stepterrain.globe import EARTH_RADIUS, look_from

    for radius, summit, clearances in ((EARTH_RADIUS, 1e5, (20.0, 1e4)), (1000.0, 1e5, (20.0, 1e4)),
                                       (1.0, 0.25, (0.01, 0.5))):  # the floor: min(1 m, 1e-6 · radius)
        for clearance in clearances:
            camera = look_from(10.0, -160.0, summit + clearance, radius=radius, max_radius=radius + summit)
            assert 0.0 < camera.near < clearance, (radius, summit, clearance, camera.near)
    # without max_radius, over the earth, as before: a thousandth of the altitude, at least 1 m
    assert look_from(46.0, 9.0, 4e5).near == 400.0 and look_from(46.0, 9.0, 200.0).near == 1.0


@pytest.mark.parametrize("north_first", [True, False])
def test_a_row_on_a_pole_gives_the_pole_its_mean(north_first):
    """A node-registered grid whose first row lies on the pole (lat = 90) with values that differ along it put the
    row's value at longitude 0 on the pole node (180 m of 170-180 m), not the row's mean that from_latlon documents
    as the pole value. Found by meshing grids with a varying pole row (helper 27). The pole row is now its mean."""
    lat = np.linspace(90.0, -90.0, 37)
    lon = np.arange(0.0, 360.0, 10.0)
    z = np.zeros((37, 36))
    z[0] = np.linspace(180.0, 170.0, 36)
    z[-1] = np.linspace(-50.0, -10.0, 36)
    if not north_first:
        lat, z = lat[::-1], z[::-1]
    globe = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu")
    vertices = globe.mesh().vertices
    radius = np.linalg.norm(vertices, axis=1)
    north, south = int(np.argmax(vertices[:, 2])), int(np.argmin(vertices[:, 2]))
    assert np.linalg.norm(vertices[north, :2]) < 1e-6 * radius[north]  # the pole node itself
    assert radius[north] - globe.radius == pytest.approx(175.0, abs=0.5)
    assert radius[south] - globe.radius == pytest.approx(-30.0, abs=0.5)


@pytest.mark.parametrize("descending", [False, True])
def test_a_longitude_axis_across_the_antimeridian_is_the_same_globe(descending):
    """A global grid whose longitudes run from 0.5 to 179.5 and on from -179.5 to -0.5 (columns not rolled to start
    at the antimeridian) was refused: "lon must be strictly monotone; it repeats or turns at index 180". Its axis is
    unwrapped across the antimeridian now, as load_dem's is: the globe is that of the rolled grid."""
    z = np.add.outer(np.linspace(-100.0, 100.0, 180), np.linspace(0.0, 500.0, 360))
    lon, lat = LON1, LAT1
    if descending:
        lon, z = lon[::-1], z[:, ::-1]
    wrapped_lon, wrapped_z = np.roll(lon, -180), np.roll(z, -180, axis=1)
    assert np.any(np.diff(wrapped_lon) * np.diff(lon)[0] < 0)  # the axis turns at the antimeridian
    rolled = Globe.from_latlon(z, lat, lon, face_size=9, device="cpu").mesh()
    wrapped = Globe.from_latlon(wrapped_z, lat, wrapped_lon, face_size=9, device="cpu").mesh()
    assert np.array_equal(rolled.faces, wrapped.faces)
    assert np.allclose(rolled.vertices, wrapped.vertices, rtol=0.0, atol=1e-3)
    with pytest.raises(InvalidInputError, match="lon must be regularly spaced"):
        Globe.from_latlon(wrapped_z, lat, np.where(np.arange(360) == 200, wrapped_lon + 0.5, wrapped_lon),
                          face_size=9, device="cpu")


@pytest.mark.parametrize("lon", [[-180.0, 180.0], [180.0, -180.0], [0.0, 360.0, 1.0]])
def test_neighbouring_longitudes_360_degrees_apart_are_refused_for_what_they_are(lon):
    """A 2-column grid at lon -180 and 180 was refused as "lon must be strictly monotone; it repeats or turns at
    index 1 (-180.0, -180.0)": values the caller never gave (the axis unwrapped across the antimeridian). The message
    names the columns as given and says they are the same meridian."""
    z = np.zeros((3, len(lon)))
    ends = rf"lon\[0\] = {lon[0]:g} and lon\[1\] = {lon[1]:g}, 360° apart: the same meridian twice"
    ends += ", a grid of no width$" if len(lon) == 2 else "; drop one of the two columns$"
    said = rf"^lon's neighbouring columns must be different meridians; got {ends}"
    with pytest.raises(InvalidInputError, match=said):
        Globe.from_latlon(z, [-10.0, 0.0, 10.0], lon, face_size=5, device="cpu")
    with pytest.raises(InvalidInputError, match=r"lon must be strictly monotone; it repeats or turns at index 1"):
        Globe.from_latlon(z, [-10.0, 0.0, 10.0], [0.0, 0.0, 1.0][: len(lon)], face_size=5, device="cpu")


def test_an_eye_exactly_on_the_surface_is_refused():
    """An eye exactly at the height of the highest node passed unchecked (|eye| >= R + highest returned early), so
    an eye on the surface of a level globe was meshed, though the contract refuses an eye "at or below the terrain
    surface"; a metre above it passes."""
    lat, lon = np.linspace(89.5, -89.5, 180), np.linspace(-179.5, 179.5, 360)
    globe = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=5, device="cpu")
    assert not globe.heights.any()
    top = globe.radius
    for eye in ((top, 0.0, 0.0), (0.0, -top, 0.0)):
        with pytest.raises(InvalidInputError, match=r"inside the planet, below the terrain surface"):
            globe.mesh(error=1000.0, camera=_camera(eye))
    assert len(globe.mesh(error=1000.0, camera=_camera((top + 1.0, 0.0, 0.0))).faces) > 0


@pytest.mark.parametrize("error", [3.5e38, 1e300])
def test_an_error_beyond_float32_still_cuts_a_padded_grid_back_to_its_rectangle(monkeypatch, error):
    """adaptive_mesh without a camera refines in one pass over the nodes, which compared e with the error alone: an
    error at or above the padding's straddle error (3e38: any larger finite error, e.g. 1e300 for "the coarsest
    mesh") left the padded square's two triangles, vertices beyond the input at (2^k, 2^k) with made-up heights.
    The node pass now refines the straddling nodes as the breadth-first levels do, and gives their mesh."""
    import stepterrain.globe as globe_module

    from .test_adaptive import assert_crack_free_rectangle

    z = np.random.default_rng(7).normal(size=(100, 150)).astype(np.float32) * 10.0
    mesh = adaptive_mesh(z, error=error, spacing=2.0)
    assert np.asarray(mesh.metadata["node_index"]).max(axis=0).tolist() == [99, 149]
    assert_crack_free_rectangle(mesh, 100, 150, (2.0, 2.0))
    monkeypatch.setattr(globe_module, "_NODE_PASS", False)
    levels = adaptive_mesh(z, error=error, spacing=2.0)
    assert len(levels.faces) == len(mesh.faces)
    assert {tuple(sorted(t)) for t in mesh.vertices[mesh.faces].reshape(-1, 9).tolist()} == \
        {tuple(sorted(t)) for t in levels.vertices[levels.faces].reshape(-1, 9).tolist()}
    square = adaptive_mesh(np.zeros((2, 2)), error=error)  # a 2 x 2 grid, padded to 3 x 3: one cell
    assert np.asarray(square.vertices)[:, :2].max() == 1.0 and len(square.faces) == 2


@pytest.mark.parametrize("radius", [6.371e5, 6.371e7])
def test_the_cli_default_eye_sees_the_whole_globe_of_any_radius(tmp_path, monkeypatch, radius):
    """--help promises a default eye at 3R with the whole globe in view, but the eye stood 3 earth radii above the
    sphere whatever --radius was: a planet ten times the earth filled the view with a patch of its surface, one a
    tenth of it was a speck. The default altitude is 3 x --radius now, and the planet's sphere lies inside every
    plane of the view."""
    import stepterrain.globe as globe_module
    from stepterrain.cli import main

    cameras = []
    real_look_from = globe_module.look_from

    def spy(*args, **kwargs):
        cameras.append((args, real_look_from(*args, **kwargs)))
        return cameras[-1][1]

    monkeypatch.setattr(globe_module, "look_from", spy)
    out = tmp_path / "g.ply"
    argv = ["-q", "globe", "--radius", f"{radius:g}", "--exaggeration", "0.01", "--face-size", "9", "-o", str(out),
            "--device", "cpu"]
    assert main(argv) == 0
    (args, camera), = cameras
    assert args == (30.0, 10.0, 3 * radius)
    planes = camera.planes()
    assert (planes[:, 3] <= -radius * 1.01).all()  # the centre at least R (and a margin) inside each plane


@pytest.fixture(scope="module")
def flat_globe() -> Globe:
    return Globe.from_latlon(np.zeros((180, 360), np.float32), LAT1, LON1, face_size=65, device="cpu")


@needs_render
def test_render_view_shows_the_view_of_a_camera_narrower_than_30_degrees(flat_globe):
    """render_view rendered every camera at a fixed 30° vertical field of view: a 10° camera's culled mesh (just
    its view) showed as a patch floating in the black, 38 % of the picture empty, and unlike the uncut mesh's
    render. It renders with the camera's own fov now: the ground fills the picture, culled or not."""
    from stepterrain.globe import look_from, render_view

    camera = look_from(45.0, 10.0, 500_000.0, tilt=20.0, fov=math.radians(10.0), aspect=1.6)
    culled = flat_globe.mesh(error=50.0, camera=camera)
    whole = flat_globe.mesh(error=50.0, camera=camera, cull=False)
    images = [render_view(m, camera, window_size=(160, 100)).astype(int) for m in (culled, whole)]
    assert (images[0].max(axis=2) > 0).all()  # no background: the ground covers the whole picture
    assert (np.abs(images[0] - images[1]).max(axis=2) > 8).mean() < 0.002


@needs_render
def test_render_view_shows_the_whole_view_of_a_camera_wider_than_30_degrees(flat_globe):
    """A 60° camera tilted 50° from 500 km up sees space above the horizon (68° from straight down) at the top of
    its view: the fixed 30° render showed only the middle of the view, ground from top to bottom."""
    from stepterrain.globe import look_from, render_view

    camera = look_from(45.0, 10.0, 500_000.0, tilt=50.0, fov=math.radians(60.0), aspect=1.6)
    image = render_view(flat_globe.mesh(error=50.0, camera=camera, cull=False), camera, window_size=(160, 100))
    ground = image.max(axis=2) > 0
    dip = math.degrees(math.acos(6_371_000.0 / 6_871_000.0))  # of the horizon below the horizontal: 22°
    # the horizon's row in the middle column: 90° - dip - 50° above the view's centre, the image 60° tall
    tan_half = math.tan(math.radians(30.0))
    horizon = 50.0 - 50.0 * math.tan(math.radians(90.0 - dip - 50.0)) / tan_half
    column = ground[:, 80]
    assert not column[: int(horizon) - 2].any() and column[int(horizon) + 2:].all(), (horizon, np.flatnonzero(column))
    whole = flat_globe.mesh(error=50.0, camera=camera)
    culled = render_view(whole, camera, window_size=(160, 100)).astype(int)
    assert (np.abs(culled - image.astype(int)).max(axis=2) > 8).mean() < 0.002


def test_render_view_refuses_a_camera_fov_beyond_what_vtk_renders(flat_globe):
    """VTK clamps a view angle to [1e-8°, 179°]: a wider camera rendered another view than its own, silently."""
    from stepterrain.globe import look_from, render_view

    camera = look_from(45.0, 10.0, 500_000.0, fov=math.radians(179.5))
    with pytest.raises(InvalidInputError, match=r"^camera fov must lie within \[1e-08, 179\] degrees to render "
                                                r"\(VTK's range\); got 179\.5 degrees"):
        render_view(flat_globe.mesh(error=1e6), camera, window_size=(64, 64))


@pytest.mark.parametrize("origin, spacing", [((1e20, 0.0), 1.0), ((0.0, -1e17), 1.0), ((1e9, 0.0), (1e-3, 1.0))])
def test_an_origin_float64_cannot_resolve_at_the_spacing_is_refused(origin, spacing):
    """adaptive_mesh had no bound on origin: with origin (1e20, 0) and spacing 1 every x collapsed to one float64
    value, a mesh of zero area without a word. Such an origin is refused as a Terrain's grid refuses it, and one
    float64 resolves still meshes with its columns apart."""
    z = np.random.default_rng(0).random((9, 9))
    with pytest.raises(InvalidInputError, match=r"^origin .* lies too far from zero for spacing .*: float64 cannot "
                                                r"keep the nodes [xy] apart out there"):
        adaptive_mesh(z, error=0.0, origin=origin, spacing=spacing, device="cpu")
    mesh = adaptive_mesh(z, error=0.0, origin=(4e11, -4e11), device="cpu")
    assert len(np.unique(mesh.vertices[:, 0])) == 9 and len(np.unique(mesh.vertices[:, 1])) == 9
    assert abs(mesh.area - 64.0) < 0.5 * 64


def test_the_cli_takes_an_eye_below_the_sphere_above_terrain_below_sea_level(tmp_path, capsys):
    """The CLI refused every --eye altitude <= 0, though terrain below the sphere (the Dead Sea's shore, -430 m; an
    ocean floor) has room above it: `--eye 31.5,35.5,-100` over a -430 m grid was refused. Any altitude above the
    terrain there is taken now; below it the library's refusal is named by --eye, and an eye at or beyond the
    centre is refused in the same words."""
    from stepterrain.cli import main

    grid, out = tmp_path / "deep.npz", tmp_path / "deep.ply"
    np.savez(grid, elevation=np.full((180, 360), -430.0, np.float32), lat=LAT1, lon=LON1)
    argv = ["-q", "globe", str(grid), "--face-size", "9", "-o", str(out), "--device", "cpu", "--eye"]
    assert main([*argv, "31.5,35.5,-100"]) == 0 and out.exists()
    out.unlink()
    assert main([*argv, "31.5,35.5,-500"]) == 2
    assert re.search(r"error: --eye 31\.5,35\.5,-500 lies below the terrain there \(the altitude is metres above the "
                     r"sphere of --radius\): camera eye \(.*\) lies inside the planet, .*terrain -430\.0 m\)",
                     capsys.readouterr().err)
    for altitude in ("-6371000", "-2e7"):
        assert main([*argv, f"31.5,35.5,{altitude}", "--no-camera"]) == 2
        assert re.search(r"error: --eye 31\.5,35\.5,-[0-9.e+]+ lies below the terrain there \(the altitude is metres "
                         r"above the sphere of --radius\): the eye at or beyond the planet's centre \(altitude <= "
                         r"-6\.371e\+06 m, the --radius\)$", capsys.readouterr().err.strip())
    assert not out.exists()


def test_masked_heights_are_named_as_masked_not_as_nan():
    """A masked array's masked entries were reported as 'NaN or infinite values' though the array held none (its
    data under the mask were 0), for the globe and the planar mesh alike; they are named as masked entries now."""
    z = np.ma.masked_array(np.zeros((180, 360)), mask=np.zeros((180, 360), bool))
    z.mask[5, 7] = z.mask[9, 2] = True
    message = r"has 2 masked \(nodata\) entries \(first at row 5, column 7\); fill them first"
    with pytest.raises(InvalidInputError, match=rf"^elevation {message}"):
        Globe.from_latlon(z, LAT1, LON1, face_size=5, device="cpu")
    with pytest.raises(InvalidInputError, match=rf"^heights {message}"):
        adaptive_mesh(z[:10, :10], error=1.0, device="cpu")
    z.mask[:] = False  # a mask with nothing masked is no nodata
    assert len(adaptive_mesh(z[:9, :9], error=1.0, device="cpu").faces) == 2


def test_the_globe_memory_check_counts_the_grids_float32_copies(budget):
    """Globe.from_latlon checked the node arrays against the memory budget but not the float32 copies of the input
    grid it makes (the grid, its contiguous or pole-averaged copy, the device's): a 1800 x 3600 grid for a 33²
    globe passed a 10 MB budget and took 50 MiB (74 with an axis reversed). The check counts three copies now."""
    lat, lon = np.linspace(89.95, -89.95, 1800), np.linspace(-179.95, 179.95, 3600)
    z = np.zeros((1800, 3600), np.int16)
    budget(10_000_000)
    with pytest.raises(OutputTooLargeError, match=r"^a globe of face_size 33 from a 1800x3600 grid would need 74\.4 "
                                                  r"MiB, over the memory budget of 9\.5 MiB; use a smaller face_size "
                                                  r"or a coarser grid"):
        Globe.from_latlon(z, lat, lon, face_size=33, device="cpu")
    budget(80 << 20)
    assert Globe.from_latlon(z, lat, lon, face_size=33, device="cpu").heights.shape == (6, 33, 33)


def test_one_bad_height_is_named_in_the_singular():
    """globe and adaptive_mesh said "elevation has 1 NaN or infinite values" and "heights has 1 masked (nodata)
    entries" (likewise "1 rows that differ" of a closing column): counts and nouns now agree."""
    z = np.zeros((5, 5))
    z[1, 2] = np.nan
    with pytest.raises(InvalidInputError, match=r"^heights has 1 NaN or infinite value \(first at row 1, column 2\)"):
        adaptive_mesh(z, error=1.0)
    z[3, 3] = np.inf
    with pytest.raises(InvalidInputError, match=r"^heights has 2 NaN or infinite values \(first at row 1, column 2\)"):
        adaptive_mesh(z, error=1.0)
    with pytest.raises(InvalidInputError, match=r"^heights has 1 masked \(nodata\) entry \(first at row 0, column 4\)"):
        adaptive_mesh(np.ma.masked_equal(np.eye(5, k=4) * 7.0, 7.0), error=1.0)
    lat, lon = np.linspace(90.0, -90.0, 19), np.linspace(-180.0, 180.0, 37)
    relief = np.zeros((19, 37))
    relief[7, -1] = 500.0  # one row whose closing column differs
    with pytest.raises(InvalidInputError, match=r"got 1 row that differs, by up to 500 m"):
        Globe.from_latlon(relief, lat, lon, face_size=9, device="cpu")


def test_the_cli_names_one_nodata_cell_in_the_singular(tmp_path, capsys):
    """``stepterrain globe`` said "'elevation' has 1 nodata cells" of a grid missing one cell."""
    from stepterrain.cli import main

    elevation = np.zeros((180, 360), np.int16)
    elevation[3, 7] = -32768
    grid = tmp_path / "grid.npz"
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1, nodata=np.array(-32768, np.int16))
    assert main(["globe", str(grid), "--face-size", "9", "--no-camera", "-o", str(tmp_path / "g.ply")]) == 2
    assert "'elevation' has 1 nodata cell (nodata -32768; first at row 3, column 7)" in capsys.readouterr().err


def test_a_user_metric_that_is_not_saturated_is_refused_not_meshed_on_unwritten_vertices():
    """A user metric that grows from a node to its children (a step in space, decided at the node's point alone) can
    refine a triangle whose neighbour, which owns the refinement node, never exists: the node's vertex was never
    emitted and its faces read an unwritten vertex_id. Globe.mesh returned faces indexing up to 1.4e9 of 4,103
    vertices, adaptive_mesh a mesh over more than its rectangle, or crashed the interpreter (a segmentation fault
    in the culling pass). Such faces are refused now, naming the metric; a saturated metric meshes as before."""
    def north(points, radius):  # decided at the node's point: a child across the line grows from 0.5 to 1.5
        return (points[:, 1] > 1500.0) + 0.5

    import stepterrain as st

    z = np.ascontiguousarray(st.sample_dem().heights[:70, :90])
    with pytest.raises(InvalidInputError, match=r"^user metric 'north' is not saturated: it grows from a node to "):
        adaptive_mesh(z, error=3.0, spacing=30.0, metrics=("geometric", north), device="cpu")
    with pytest.raises(InvalidInputError, match=r"^user metric '<lambda>' is not saturated"):
        Globe.sample(face_size=65).mesh(error=200.0, metrics=("geometric", lambda p, r: (p[:, 2] > 0) * 1.0))

    def sphere(points, radius):  # decided by the whole bounding sphere: nested spheres never grow across the line
        return (points[:, 1] + radius > 1500.0) + 0.5

    mesh = adaptive_mesh(z, error=3.0, spacing=30.0, metrics=("geometric", sphere), device="cpu")
    assert np.asarray(mesh.faces).max() < len(mesh.vertices)
    assert (mesh.area_faces * mesh.face_normals[:, 2]).sum() == pytest.approx(69 * 89 * 900.0, rel=1e-9)


def test_a_user_metric_that_is_not_saturated_is_refused_where_its_crack_had_every_vertex(monkeypatch):
    """The unwritten-vertex check above catches a refined triangle whose new node's vertex no triangle emits; when
    the refined triangle itself owns that node, the vertex is emitted and its coarser neighbour across the
    hypotenuse keeps the edge whole: a T-junction. Globe.mesh and adaptive_mesh returned such cracked meshes
    without a word (a random half-space metric on a 33 x 33 grid: 10 meshes of 200). The leaves of a refinement
    steered by a user metric are checked to tile the sphere / the square now, naming the metric."""
    import stepterrain.globe as globe_module
    from stepterrain.mesh import boundary_edges

    z = np.random.default_rng(0).normal(size=(33, 33)).astype(np.float32)
    planar_salt = np.array([-1.11, -0.29, -0.26])
    globe_salt = np.array([0.9, 0.8, 0.0])

    def planar(points, radius):  # decided at the node's point: stripes, not saturated
        return (np.sin(points @ planar_salt) > 0) * 1e9

    def on_globe(points, radius):
        return (np.sin(points @ globe_salt * 7.3e-5) > 0) * 1e9

    globe = Globe.sample(face_size=17, device="cpu")
    with pytest.raises(InvalidInputError, match=r"^user metric 'planar' is not saturated: .*: a hanging node "
                                                r"\(a crack\) on 1 edge of the mesh; "):
        adaptive_mesh(z, error=1.0, metrics=("geometric", planar), device="cpu")
    with pytest.raises(InvalidInputError, match=r"^user metric 'on_globe' is not saturated: .*: a hanging node "
                                                r"\(a crack\) on \d+ edges of the mesh"):
        globe.mesh(error=1.0, metrics=("geometric", on_globe))
    # what was returned: meshes with every vertex written, and cracks (edges used once inside the square / sphere)
    launch_chunked = globe_module.launch_chunked

    def without_the_check(kernel, *args, **kwargs):
        if kernel is not cs.count_hanging_edges:
            launch_chunked(kernel, *args, **kwargs)

    monkeypatch.setattr(globe_module, "launch_chunked", without_the_check)
    cracked = globe.mesh(error=1.0, metrics=("geometric", on_globe))
    assert np.asarray(cracked.faces).max() < len(cracked.vertices) and not cracked.is_watertight
    flat = adaptive_mesh(z, error=1.0, metrics=("geometric", planar), device="cpu")
    ends = np.asarray(flat.vertices)[boundary_edges(np.asarray(flat.faces)).reshape(-1)][:, :2].reshape(-1, 2, 2)
    border = [(ends[:, 0, k] == ends[:, 1, k]) & np.isin(ends[:, 0, k], (0.0, 32.0)) for k in (0, 1)]
    assert (~(border[0] | border[1])).sum() == 3
    monkeypatch.undo()
    # saturated metrics (the whole bounding sphere) still mesh, crack-free
    closed = globe.mesh(error=1.0, metrics=("geometric", lambda p, r: (p[:, 2] + r > 0) * 1e9))
    assert closed.is_watertight and closed.euler_number == 2


def test_an_eye_below_every_node_is_refused_naming_the_terrain_in_its_direction():
    """An eye below the lowest node was refused naming the lowest node's height as "the surface there": 4.5 km under
    sea level beneath the 6 km mountain the message said "terrain -4000.0 m" (on the real relief, an eye 11 km under
    the Himalaya read the Mariana trench's -8396 m). It names the terrain in the eye's direction now, as for an eye
    within the relief; the eye at the centre names the lowest node."""
    globe = _mountain_globe()
    R = globe.radius
    lowest = float(globe.heights.min())
    assert lowest == pytest.approx(-4000.0, abs=1.0)
    with pytest.raises(InvalidInputError, match=r"\|eye\| = 6366500\.0 m, the surface there 637[5-7]\d{3}\.\d m from "
                                                r"the centre \(radius 6371000\.0 m, terrain \+[5-6]\d{3}\.\d m\)"):
        globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 0.0, R - 4500.0)))
    with pytest.raises(InvalidInputError, match=r"terrain -1000\.0 m\)"):  # the plateau, not the sea floor
        globe.mesh(error=1000.0, camera=_camera(_eye(0.0, 90.0, R - 4500.0)))
    with pytest.raises(InvalidInputError, match=rf"\|eye\| = 0\.0 m, .* terrain {lowest:+.1f} m\)"):
        globe.mesh(error=1000.0, camera=Camera(eye=(0.0, 0.0, 0.0), target=(1.0, 0.0, 0.0)))


@needs_render
def test_render_view_never_shows_more_than_the_camera_saw(flat_globe):
    """render_view's horizontal extent followed the window, and its window defaulted to 1280 x 800 whatever the
    camera: a 9:16 camera's culled mesh rendered by default (or in any window wider than 9:16) showed the ground the
    camera had culled away as black at the picture's sides (16 % of it). The window now defaults to the camera's
    viewport, and a wider one keeps the camera's horizontal extent: culled or not, the same picture, no black."""
    from stepterrain.globe import look_from, render_view

    camera = look_from(45.0, 10.0, 500_000.0, tilt=20.0, fov=math.radians(20.0), aspect=9 / 16)
    culled = flat_globe.mesh(error=50.0, camera=camera)
    whole = flat_globe.mesh(error=50.0, camera=camera, cull=False)
    assert render_view(culled, camera).shape == (800, 450, 3)  # the camera's viewport
    for size in [(90, 160), (160, 90), (100, 100)]:
        images = [render_view(m, camera, window_size=size).astype(int) for m in (culled, whole)]
        assert images[0].shape == (size[1], size[0], 3)
        assert (images[0].max(axis=2) > 0).all(), size  # no background: the ground covers the whole picture
        assert (np.abs(images[0] - images[1]).max(axis=2) > 8).mean() < 0.002, size
    with pytest.raises(InvalidInputError, match=r"^camera viewport 4x3 is no window to render .*; give window_size"):
        render_view(culled, Camera(eye=camera.eye, target=camera.target, up=camera.up, viewport=(4, 3)))


@needs_render
def test_render_view_close_over_the_ground_does_not_clip_the_ground_away(flat_globe):
    """render_view's near plane lay at far / 10^4 wherever the eye was inside the mesh's box: 1.3-1.6 km for the
    earth. From 10 m (or 300 m, tilted 70°) the ground in front of the eye was clipped away and the picture showed the
    inside of the far side of the globe instead, culled mesh or not. The near plane now stays within half the eye's
    distance to the mesh: every pixel shows ground near the eye (coloured red; vertices 1000 km off and more blue)."""
    from stepterrain.globe import look_from, render_view

    for altitude, tilt in ((10.0, 45.0), (300.0, 70.0)):
        camera = look_from(45.0, 10.0, altitude, tilt=tilt, aspect=1.6)
        for cull in (True, False):
            mesh = flat_globe.mesh(error=50.0, camera=camera, cull=cull)
            near = np.linalg.norm(mesh.vertices - np.array(camera.eye), axis=1) < 1e6
            mesh.visual.vertex_colors = np.where(near[:, None], [255, 0, 0, 255], [0, 0, 255, 255]).astype(np.uint8)
            image = render_view(mesh, camera, window_size=(160, 100)).astype(int)
            assert (image[:, :, 0] > image[:, :, 2]).all(), (altitude, tilt, cull)


def test_the_cli_refuses_view_options_that_do_nothing_and_records_only_what_was_applied(tmp_path, capsys):
    """``globe --no-camera --metrics geometric,clip`` and ``--no-camera --no-cull`` (or ``--no-cull`` without the
    clip metric) were accepted and did nothing: the library ignores the view's metrics without a camera and culls
    only by the clip metric; the progress line and the mesh's metadata named 'geometric,distance,clip' and an eye
    for a mesh refined by the geometric error alone. Such options are refused by name now, and a --no-camera mesh
    records the metrics it was refined by (geometric) and no eye."""
    from stepterrain.cli import main
    from stepterrain.export import read_mesh

    out = tmp_path / "g.glb"
    base = ["globe", "--face-size", "9", "--device", "cpu", "-o", str(out)]
    for extra, message in [
        (["--no-camera", "--metrics", "geometric,clip"], "error: --metrics clip needs the camera: not with "
                                                          "--no-camera, which refines by the geometric error alone"),
        (["--no-camera", "--metrics", "distance,geometric,clip"], "error: --metrics distance,clip need the camera"),
        (["--no-camera", "--no-cull"], "error: --no-cull applies only with the camera"),
        (["--metrics", "geometric,distance", "--no-cull"], "error: --no-cull applies only with the clip metric "
                                                           "(only it culls); got --metrics geometric,distance"),
    ]:
        assert main([*base, *extra]) == 2, extra
        assert message in capsys.readouterr().err, extra
        assert not out.exists()

    assert main([*base, "--no-camera", "--error", "0"]) == 0
    assert "metrics geometric\n" in capsys.readouterr().err
    meta = read_mesh(out).metadata
    assert meta["metrics"] == "geometric" and "eye_lat_lon_alt" not in meta
    assert len(read_mesh(out).faces) == 12 * 8**2  # error 0 without a camera: the full-resolution sphere

    assert main([*base, "--eye", "46,9,400000", "--no-cull"]) == 0  # with the camera: as before
    meta = read_mesh(out).metadata
    assert meta["metrics"] == "geometric,distance,clip" and meta["eye_lat_lon_alt"] == [46.0, 9.0, 400000.0]


def test_drape_colors_given_the_mesh_says_to_pass_its_vertices():
    """drape_texture takes the mesh, so a user passed the mesh to drape_colors too, and was told 'vertices must be a
    (V, 3) array of planet-centred positions (real numbers); got dtype object: <trimesh.Trimesh(...)>'. The message
    now says to pass mesh.vertices; with them the colours are one RGBA per vertex, sampled from the image."""
    from stepterrain.globe import drape_colors

    mesh = _small_globe().mesh()
    image = np.zeros((90, 180, 3), np.uint8)
    image[:45] = (200, 10, 10)  # the northern hemisphere red, the southern black
    message = (r"^vertices must be a \(V, 3\) array of planet-centred positions; got a trimesh\.Trimesh: pass its "
               r"vertices, mesh\.visual\.vertex_colors = drape_colors\(mesh\.vertices, image\)$")
    with pytest.raises(InvalidInputError, match=message):
        drape_colors(mesh, image)
    colors = drape_colors(mesh.vertices, image)
    assert colors.shape == (len(mesh.vertices), 4)
    north = np.asarray(mesh.vertices)[:, 2] > 0.1 * np.linalg.norm(mesh.vertices, axis=1)
    assert (colors[north] == (200, 10, 10, 255)).all() and (colors[~north & (np.asarray(mesh.vertices)[:, 2] < 0)]
                                                              [:, 0] < 200).all()


def test_the_cli_refuses_bounds_that_nothing_measures_and_records_the_shapes_only_where_measured(tmp_path, capsys):
    """``globe --no-camera --bounds sphere`` (or --bounds with --metrics geometric) was accepted and made the same
    mesh as cones: the bounding shapes are measured only by the distance and clip metrics, against the eye and the
    view; the progress line and the metadata said 'spheres' all the same, and a --no-camera mesh recorded
    'bounds: cone'. Such a --bounds is refused by name now, and the shapes are recorded only where measured."""
    from stepterrain.cli import main
    from stepterrain.export import read_mesh

    out = tmp_path / "g.glb"
    base = ["globe", "--face-size", "9", "--device", "cpu", "-o", str(out)]
    for extra, why in ((["--no-camera"], "--no-camera"), (["--metrics", "geometric"], "--metrics geometric")):
        assert main([*base, *extra, "--bounds", "sphere"]) == 2, extra
        assert (f"error: --bounds applies only with the camera and the distance or clip metric (the bounding shapes "
                f"are measured against the eye and the view); got --bounds sphere with {why}"
                in capsys.readouterr().err), extra
        assert not out.exists()
        assert main([*base, *extra]) == 0
        assert "error 500, metrics geometric\n" in capsys.readouterr().err
        assert "bounds" not in read_mesh(out).metadata
        out.unlink()

    assert main([*base, "--bounds", "sphere", "--metrics", "geometric,distance"]) == 0  # measured: as before
    assert "error 500, spheres, metrics geometric,distance\n" in capsys.readouterr().err
    assert read_mesh(out).metadata["bounds"] == "sphere"
    assert main(base) == 0
    assert read_mesh(out).metadata["bounds"] == "cone"


def test_the_views_options_with_no_camera_and_no_png_are_refused_by_name(tmp_path, capsys):
    """``globe --no-camera --eye 46,9,400000`` (or --tilt, --heading, --size, --view-angle) without --png was
    accepted and did nothing: the mesh is refined by the geometric error alone and nothing is rendered from the eye,
    so the run made the mesh it makes without them. They are refused by name now; with --png they place the render,
    and with the camera they shape the view, so those runs pass."""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    base = ["-q", "globe", "--face-size", "9", "--error", "0", "-o", str(out), "--device", "cpu"]
    for extra, names, verb in (
        (["--eye", "46,9,400000"], "--eye", "applies"),
        (["--tilt", "30", "--heading", "90"], "--tilt and --heading", "apply"),
        (["--size", "64x48"], "--size", "applies"),
        (["--view-angle", "20"], "--view-angle", "applies"),
        (["--eye", "46,9,400000", "--tilt", "30", "--size", "64x48"], "--eye, --tilt and --size", "apply"),
    ):
        assert main([*base, "--no-camera", *extra]) == 2
        err = capsys.readouterr().err
        assert f"error: {names} {verb} only with the camera or a --png render (with --no-camera the mesh is refined " \
               "by the geometric error alone); got" in err, err
        assert not out.exists()
        with_camera = extra if "--eye" in extra else [*extra, "--eye", "46,9,400000"]
        assert main([*base, *with_camera]) == 0 and out.exists()  # with the camera: the view
        out.unlink()
    assert main([*base, "--no-camera"]) == 0 and out.exists()


def test_the_views_direction_without_the_clip_metric_and_no_png_is_refused_by_name(tmp_path, capsys):
    """``globe --metrics geometric,distance --tilt 30`` (or --heading, --view-angle, --size) without --png was
    accepted and wrote the mesh that run writes without them: the view's direction, angle and aspect make only the
    clip metric's (and the culling's) planes, and the geometric and distance metrics read the eye's position alone.
    Refused by name now; --eye still shapes such a mesh with the distance metric, and with the clip metric or a --png
    the options pass. (The geometric metric alone reads no --eye either: refused too, see
    test_cli_truthfulness.py; its runs here leave --eye out, and its message no longer says it reads the eye.)"""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    base = ["-q", "globe", "--face-size", "9", "--error", "0", "-o", str(out), "--device", "cpu",
            "--eye", "46,9,400000"]
    bytes_of = {}
    for metrics in ("geometric", "geometric,distance"):
        eyed = base if metrics != "geometric" else base[:-2]
        assert main([*eyed, "--metrics", metrics]) == 0
        bytes_of[metrics] = out.read_bytes()
        out.unlink()
        why = ("(the distance metric reads only the --eye position)" if metrics != "geometric" else
               "(the geometric metric measures each node's own error, nothing of the view)")
        for extra, names, verb in (
            (["--tilt", "20", "--heading", "90"], "--tilt and --heading", "apply"),
            (["--size", "64x48"], "--size", "applies"),
            (["--view-angle", "20"], "--view-angle", "applies"),
        ):
            assert main([*eyed, "--metrics", metrics, *extra]) == 2
            err = capsys.readouterr().err
            assert (f"error: {names} {verb} only with the clip metric or a --png render {why}; got "
                    f"{'them' if verb == 'apply' else 'it'} with --metrics {metrics} and no --png") in err, err
            assert not out.exists()
            # with the clip metric the view shapes the mesh: the options pass
            assert main([*base[:-2], "--eye", "46,9,400000", "--metrics", f"{metrics},clip", *extra]) == 0
            out.unlink()
    assert main([*base[:-1], "46,9,800000", "--metrics", "geometric,distance"]) == 0  # the eye's position: used
    assert out.read_bytes() != bytes_of["geometric,distance"]


def test_the_cli_names_unknown_and_repeated_metrics_in_its_own_terms(tmp_path, capsys):
    """``globe --metrics clip,bogus`` said "--metrics must be names among ('geometric', 'distance', 'clip') or
    callables", offering callables no option can pass; ``--metrics geometric,geometric`` was accepted (the library
    takes a set: the mesh of ``geometric``) while the metadata and progress line named the metric twice. Both are
    refused in the option's terms now, before any work."""
    from stepterrain.cli import main

    out = tmp_path / "g.ply"
    base = ["globe", "--face-size", "9", "-o", str(out), "--device", "cpu", "--metrics"]
    for metrics, why in (("clip,bogus", "('bogus' unknown)"), ("Geometric,x", "('Geometric', 'x' unknown)")):
        assert main([*base, metrics]) == 2
        assert capsys.readouterr().err == (f"stepterrain globe: error: --metrics must be names among geometric, "
                                           f"distance, clip separated by commas; got {metrics!r} {why}\n")
    assert main([*base, "geometric,clip,geometric"]) == 2
    assert capsys.readouterr().err == ("stepterrain globe: error: --metrics names each metric once; got "
                                       "'geometric,clip,geometric' (geometric repeated)\n")
    assert not out.exists()
    assert main(["-q", *base, "geometric,clip"]) == 0 and out.exists()


def test_a_rectangle_does_not_refine_or_measure_its_padding():
    """adaptive_mesh pads an (H, W) grid to (2^k + 1)², and a rectangle paid for the whole square: every node of the
    padding had its true error measured over the repeated edge, and the refinement ran through the padding down to
    wherever those errors led (with error=0 to every cell), all of it dropped from the mesh (Big Tujunga, 643 x 1197,
    took 4x the time of a square with as many cells). The padding's triangles now count as no error and refine
    only where they straddle the input's border; the nodes far out in it are not even visited."""
    import stepterrain.globe as globe_module
    from stepterrain._device import resolve_device

    from .test_adaptive import assert_crack_free_rectangle

    z = np.random.default_rng(3).normal(size=(3, 129)).astype(np.float32)
    for node_pass in (True, False):
        globe_module._NODE_PASS = node_pass
        try:
            for shape, error in (((3, 129), 0.0), ((129, 3), 0.0), ((3, 129), 0.5)):
                grid = z if shape == (3, 129) else np.ascontiguousarray(z.T)
                mesh = adaptive_mesh(grid, error=error)
                assert_crack_free_rectangle(mesh, *shape)
                # the triangles the refinement visited: about twice the mesh's, not the 2 x 128² of the padded square
                assert sum(mesh.metadata["levels"]) < 6 * 2 * 128 * 2, (shape, error, node_pass)
        finally:
            globe_module._NODE_PASS = True
    device = resolve_device("cpu")
    padded = np.pad(z, ((0, 126), (0, 0)), mode="edge")
    grid = globe_module._planar_grid(padded, (1.0, 1.0), z.shape, shapes=False, device=device)
    params = globe_module._node_parameters(grid, faces=1, levels=14, device=device, shapes=False)
    written = np.count_nonzero(params.values.numpy()[:, 0])
    assert written < 0.2 * 129 * 129  # the nodes near the input's three rows (and the coarse ones), not all 129²


_SHAPES = [(3, 129), (129, 3), (2, 9), (37, 200), (200, 37), (70, 260), (65, 40)]


@pytest.mark.parametrize("shape", _SHAPES)
@pytest.mark.parametrize("node_pass", [True, False])
def test_a_rectangle_keeps_the_true_bound_and_is_crack_free(shape, node_pass, monkeypatch):
    """Not refining the padding must leave the rectangle's mesh what it was: the error a true bound over every
    input node (brute force), welded, counter-clockwise, its border the rectangle's only (no crack where the
    refinement stops at the padding), vertices at the input's nodes, with a view and user metrics too."""
    import stepterrain.globe as globe_module

    from .test_adaptive import assert_crack_free_rectangle, dem, true_errors

    monkeypatch.setattr(globe_module, "_NODE_PASS", node_pass)
    rows, cols = shape
    z = dem("big_tujunga_srtm_30m_utm11n.npz", rows, cols)
    z = z + np.random.default_rng(rows * cols).normal(0.0, 0.5, z.shape).astype(np.float32)
    spacing = (30.0, 20.0)
    for error in (0.0, 1.0, 8.0):
        mesh = adaptive_mesh(z, error=error, spacing=spacing)
        assert_crack_free_rectangle(mesh, rows, cols, spacing)
        assert true_errors(mesh, z, spacing).max() <= error + 1e-3
        index = np.asarray(mesh.metadata["node_index"])
        assert index.min() == 0 and index[:, 0].max() == rows - 1 and index[:, 1].max() == cols - 1
        np.testing.assert_array_equal(mesh.vertices[:, 2], z[index[:, 0], index[:, 1]])
    users = adaptive_mesh(z, error=2.0, spacing=spacing,
                          metrics=("geometric", lambda p, r: 1.0 + (p[:, 0] - r < 15.0 * cols)))
    assert_crack_free_rectangle(users, rows, cols, spacing)
    assert true_errors(users, z, spacing).max() <= 2.0 + 1e-3
    eye = (-300.0, -300.0, float(z.max()) + 500.0)
    camera = Camera(eye=eye, target=(30.0 * cols, 20.0 * rows, float(z.min())), fov=0.9)
    viewed = adaptive_mesh(z, error=1.0, spacing=spacing, camera=camera, cull=False)
    assert_crack_free_rectangle(viewed, rows, cols, spacing)


def test_a_square_or_rectangle_meshes_as_before_the_padding_was_skipped():
    """The padding's errors never decided a triangle inside the rectangle: the same faces on the same nodes as
    before it was skipped (digests of the meshes then), for a square, which has no padding, and rectangles."""
    import hashlib

    from .test_adaptive import dem

    z = dem("big_tujunga_srtm_30m_utm11n.npz", 150, 150)
    camera = Camera(eye=(1000.0, 1000.0, 3500.0), target=(4000.0, 4000.0, 1000.0), fov=0.9)
    expected = {(129, 129): (15354, "5baf4491733294a9", 2095, "503caa91cd981e10"),
                (100, 150): (13335, "58e1a798f59ad680", 2055, "9998d20c844e5f23"),
                (150, 100): (14113, "aa8a24760d3033f6", 2240, "deb0857b337d7a06")}

    def digest(mesh):
        h = hashlib.sha256()
        h.update(np.ascontiguousarray(np.asarray(mesh.faces, dtype=np.int64)).tobytes())
        h.update(np.ascontiguousarray(np.asarray(mesh.metadata["node_index"], dtype=np.int64)).tobytes())
        return h.hexdigest()[:16]

    for (rows, cols), want in expected.items():
        grid = np.ascontiguousarray(z[:rows, :cols])
        plain = adaptive_mesh(grid, error=3.0, spacing=30.0)
        viewed = adaptive_mesh(grid, error=3.0, spacing=30.0, camera=camera, cull=False)
        assert (len(plain.faces), digest(plain), len(viewed.faces), digest(viewed)) == want, (rows, cols)


def test_a_long_strip_is_not_padded_to_its_whole_square():
    """A 50 x 16385 strip (0.8 M nodes) took 21 s, 19 of them in np.pad's edge-repeated 16385² copy (1 GB) of which
    the mesh reads a band along the strip and the coarse nodes: the heights are padded in place now, at the entries
    something reads (the rest of the square is never touched), with the mesh unchanged."""
    import stepterrain.globe as globe_module
    from stepterrain._device import resolve_device

    from .test_adaptive import assert_crack_free_rectangle, true_errors

    z = (1.0 + np.random.default_rng(5).random((3, 1025))).astype(np.float32)
    grid = globe_module._planar_grid(z, (1.0, 1.0), z.shape, shapes=False, device=resolve_device("cpu"), n=1025)
    heights = grid.heights.numpy().reshape(1025, 1025)
    np.testing.assert_array_equal(heights[:3], z)  # the input itself
    np.testing.assert_array_equal(heights[3:12], np.broadcast_to(z[-1], (9, 1025)))  # its last row repeated below
    assert np.count_nonzero(heights) < 0.05 * heights.size  # not the whole square
    padded = np.pad(z, ((0, 1022), (0, 0)), mode="edge")
    written = heights != 0
    np.testing.assert_array_equal(heights[written], padded[written])  # what is written is the edge repeated
    for error in (0.0, 0.3):
        mesh = adaptive_mesh(z, error=error)
        assert_crack_free_rectangle(mesh, 3, 1025)
        assert true_errors(mesh, z).max() <= error + 1e-6


def test_a_distance_scale_that_changes_nothing_is_refused():
    """``distance_scale`` is ℓ of the distance metric; without a camera, or with metrics that leave the distance
    out, it was accepted and ignored (the mesh the same whatever it was). Refused now, naming why; with a camera and
    the distance metric it still shapes the mesh."""
    z = np.add.outer(np.sin(np.arange(33.0) / 3.0), np.cos(np.arange(33.0) / 4.0)) * 20.0
    eye = Camera(eye=(16.0, 16.0, 200.0), target=(16.0, 16.0, 0.0), up=(0.0, 1.0, 0.0))
    with pytest.raises(InvalidInputError, match=r"^distance_scale applies only with a camera and the 'distance' "
                                                r"metric .*; got distance_scale=50\.0 without a camera$"):
        adaptive_mesh(z, error=0.5, distance_scale=50.0, device="cpu")
    with pytest.raises(InvalidInputError, match=r"got distance_scale=50\.0 with metrics clip, geometric \(no "
                                                r"'distance'\)$"):
        adaptive_mesh(z, error=0.5, camera=eye, metrics=("geometric", "clip"), distance_scale=50.0, device="cpu")
    near = adaptive_mesh(z, error=0.5, camera=eye, distance_scale=20.0, device="cpu")
    far = adaptive_mesh(z, error=0.5, camera=eye, distance_scale=2000.0, device="cpu")
    assert len(far.faces) > len(near.faces)  # a longer ℓ tolerates less at the same distance: it still counts
    lat = np.linspace(89.5, -89.5, 18)
    lon = np.linspace(-175.0, 175.0, 36)
    globe = Globe.from_latlon(np.zeros((18, 36)), lat, lon, face_size=9, device="cpu")
    with pytest.raises(InvalidInputError, match=r"got distance_scale=1000\.0 without a camera$"):
        globe.mesh(error=10.0, distance_scale=1000.0)


def _glb_texture(path):
    """(mimeType, bytes) of a GLB's one embedded image."""
    import json
    import struct

    data = path.read_bytes()
    length = struct.unpack_from("<I", data, 12)[0]
    tree = json.loads(data[20 : 20 + length])
    binary = data[20 + length + 8 :]
    (image,) = tree["images"]
    view = tree["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    return image["mimeType"], binary[start : start + view["byteLength"]]


def test_a_jpeg_texture_draped_on_the_globe_is_embedded_as_the_file_s_bytes(tmp_path, capsys):
    """``stepterrain globe --texture earth.jpg`` and ``drape_texture(mesh, "earth.jpg")`` decoded the JPEG to an array
    and embedded it as a lossless PNG: the 3840 x 1920 Blue Marble, 4.7 MB, was 14.7 MB in the GLB. The drape uses
    the image as it is (no flip, crop or padding: the antimeridian wraps by UVs past 1), so an RGB JPEG's own file
    is embedded now, as save_mesh embeds an image opened from a JPEG; the texture's pixels are the same. A greyscale
    JPEG (converted to RGB) and a PNG are embedded as their pixels, as before. An OBJ's texture image is the .jpeg
    file, and the CLI's check that it replaces none of its inputs names that file."""
    from PIL import Image

    from stepterrain.cli import main
    from stepterrain.export import save_mesh
    from stepterrain.globe import drape_texture

    rng = np.random.default_rng(5)
    pixels = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    pixels[:, :32] = (200, 30, 40)
    photo = tmp_path / "earth.jpg"
    Image.fromarray(pixels).save(photo, format="JPEG", quality=90)
    source = photo.read_bytes()
    with Image.open(photo) as decoded:
        expected = np.asarray(decoded.convert("RGB"))
    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    textured = drape_texture(mesh, photo)
    assert np.array_equal(np.asarray(textured.visual.material.image), expected)
    assert np.array_equal(textured.visual.uv, drape_texture(mesh, expected).visual.uv)
    mime, data = _glb_texture(save_mesh(textured, tmp_path / "lib.glb"))
    assert mime == "image/jpeg" and data[: len(source)] == source and data[len(source) :].strip(b"\0 ") == b""
    # the CLI: GLB and OBJ
    base = ["-q", "globe", "--face-size", "9", "--error", "0", "--no-camera", "--texture", str(photo)]
    assert main([*base, "-o", str(tmp_path / "cli.glb")]) == 0
    mime, data = _glb_texture(tmp_path / "cli.glb")
    assert mime == "image/jpeg" and data[: len(source)] == source
    assert main([*base, "-o", str(tmp_path / "obj" / "earth.obj")]) == 0
    assert sorted(p.name for p in (tmp_path / "obj").iterdir()) == ["earth.mtl", "earth.obj",
                                                                    "earth_material_0.jpeg"]
    assert (tmp_path / "obj" / "earth_material_0.jpeg").read_bytes() == source
    # a texture named as the OBJ's .jpeg image is refused before any work, not replaced
    clash = tmp_path / "obj" / "earth_material_0.jpeg"
    assert main([*base[:-1], str(clash), "-o", str(tmp_path / "obj" / "earth.obj")]) == 2
    assert "writes 'earth_material_0.jpeg' beside it (its texture image), which is the --texture file" \
        in capsys.readouterr().err
    assert clash.read_bytes() == source
    # a greyscale JPEG and a PNG: their pixels, as PNG
    Image.fromarray(pixels[..., 0]).save(tmp_path / "grey.jpg", format="JPEG")
    Image.fromarray(pixels).save(tmp_path / "earth.png")
    for name in ("grey.jpg", "earth.png"):
        mime, data = _glb_texture(save_mesh(drape_texture(mesh, tmp_path / name), tmp_path / f"{name}.glb"))
        assert mime == "image/png", name


@pytest.mark.parametrize("orientation", [3, 6])
def test_a_tiff_texture_with_an_orientation_tag_is_draped_as_stored(tmp_path, orientation):
    """drape_texture(mesh, "earth.tif") and ``globe --texture earth.tif`` of a TIFF with an Orientation tag (274):
    Pillow 13 turns every TIFF by the tag as it decodes it, so the drape took the turned pixels (a 32 x 64 texture
    draped 64 x 32: the whole globe's texture turned; an uncompressed grey one turned 90 degrees came out scrambled),
    where a PNG's or JPEG's EXIF orientation is not applied: the texture is the file's stored pixels. Now a TIFF is
    draped as stored too, as GDAL reads it."""
    from PIL import Image

    from stepterrain.cli import main
    from stepterrain.globe import drape_texture

    rng = np.random.default_rng(7)
    rgb = rng.integers(0, 256, (32, 64, 3), dtype=np.uint8)
    grey = rng.integers(0, 256, (32, 64), dtype=np.uint8)
    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    for name, pixels, expected, options in [("rgb.tif", rgb, rgb, {"compression": "tiff_deflate"}),
                                            ("grey.tif", grey, np.repeat(grey[:, :, None], 3, axis=2), {})]:
        path = tmp_path / name
        Image.fromarray(pixels).save(path, tiffinfo={274: orientation}, **options)
        textured = drape_texture(mesh, path)
        assert np.array_equal(np.asarray(textured.visual.material.image.convert("RGB")), expected), name
        assert np.array_equal(textured.visual.uv, drape_texture(mesh, expected).visual.uv)
    # the CLI drapes the same stored pixels (an OBJ's side image is them)
    assert main(["-q", "globe", "--face-size", "9", "--error", "0", "--no-camera", "--texture",
                 str(tmp_path / "rgb.tif"), "-o", str(tmp_path / "obj" / "earth.obj")]) == 0
    side = [p for p in (tmp_path / "obj").iterdir() if p.suffix == ".png"]
    assert len(side) == 1
    with Image.open(side[0]) as written:
        assert np.array_equal(np.asarray(written.convert("RGB")), rgb)


def test_a_geotiff_texture_that_is_not_global_is_refused(tmp_path, capsys):
    """drape_texture(mesh, "dem.tif") and ``globe --texture dem.tif`` of a GeoTIFF that its georeferencing places over
    a region (the Front Range DEM, 0.63 degrees square) or in a projected CRS (Big Tujunga, UTM 11N) stretched it over
    the whole globe, silently (a DEM's 16-bit heights as a near-black texture). It is refused now, naming the
    extent; a global one from 0 to 360 degrees (draped 180 degrees off) is shifted to start at 180 W; the global Blue
    Marble GeoTIFF (-180..180, -90..90) drapes as before."""
    from stepterrain.cli import main
    from stepterrain.globe import drape_texture

    from .conftest import shared_file

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    regional = shared_file("front_range_srtmgl3_3arcsec.tif")
    with pytest.raises(InvalidInputError, match=r"global plate-carr.e image .*longitudes -105\.816 to -105\.185"):
        drape_texture(mesh, regional)
    with pytest.raises(InvalidInputError, match="projected CRS"):
        drape_texture(mesh, shared_file("big_tujunga_srtm_30m_utm11n.tif"))
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    shifted = tmp_path / "earth_0_360.tif"  # global, but column 0 at 0E: draped 180 degrees off
    data = np.broadcast_to(np.arange(180, dtype=np.uint8)[None, :, None], (90, 180, 3))  # each column its own value
    with rasterio.open(shifted, "w", driver="GTiff", width=180, height=90, count=3, dtype="uint8", crs="EPSG:4326",
                       transform=Affine(2.0, 0.0, 0.0, 0.0, -2.0, 90.0)) as dataset:
        dataset.write(np.moveaxis(data, 2, 0))
    drawn = np.asarray(drape_texture(mesh, shifted).visual.material.image)
    np.testing.assert_array_equal(drawn, np.roll(data, 90, axis=1))  # its column 90 (180E = 180W) first
    textured = drape_texture(mesh, shared_file("earth_day_bluemarble_3840x1920.tif"))
    assert textured.visual.material.image.size == (3840, 1920)
    assert main(["-q", "globe", "--face-size", "9", "--texture", str(regional), "-o", str(tmp_path / "g.glb")]) == 2
    assert "--texture" in capsys.readouterr().err and not (tmp_path / "g.glb").exists()


def _two_pole_texture():
    """A plate-carrée texture whose poles differ: ice white south of 70° S, dark blue north of 70° N, green between."""
    image = np.empty((128, 256, 3), np.uint8)
    image[:] = (40, 140, 40)
    image[:20] = (10, 10, 110)  # north
    image[-20:] = (235, 235, 235)  # south
    return image


def _assert_poles_show_their_own_colours(textured, image):
    """Unlit renders from a camera over each pole and over the equator at the antimeridian: the middle of each
    picture shows the image's own colour there (the north pole's, the south pole's, the equator's)."""
    from stepterrain.globe import EARTH_RADIUS, look_from
    from stepterrain.render import render_textured_mesh

    for latitude, colour in ((90.0, image[0, 0]), (-90.0, image[-1, 0]), (0.0, image[64, 0])):
        camera = look_from(latitude, 180.0, 3 * EARTH_RADIUS)
        picture = render_textured_mesh(textured, window_size=(160, 160), lighting=False, anti_aliasing=False,
                                       camera=[tuple(camera.eye), tuple(camera.target), tuple(camera.up)])
        middle = picture[70:90, 70:90].reshape(-1, 3).astype(float)
        assert np.abs(middle - colour).max() <= 12, (latitude, middle.mean(axis=0), colour)


def test_a_globe_drape_samples_its_poles_without_the_other_pole_s_colour(tmp_path):
    """The textured globe's poles, with mipmaps, showed a grey diamond at the north pole of the Blue Marble and a
    dark spot at its white south pole: glTF's default sampler (trimesh writes none) and VTK's texture repeat the
    image in v as well as in u, so at the coarse mip levels the pole triangles take (their u span of 45 to 90
    degrees of longitude) each pole's texels blended with the other pole's. drape_texture now asks for REPEAT in u
    and CLAMP_TO_EDGE in v: the GLB's texture gets that sampler (valid glTF) and the render clamps v."""
    import json
    import struct

    from stepterrain.export import save_mesh
    from stepterrain.globe import drape_texture

    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    mesh = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=33, device="cpu").mesh()
    textured = drape_texture(mesh, _two_pole_texture())
    uv = np.asarray(textured.visual.uv)
    assert np.ptp(uv[textured.faces][:, :, 0], axis=1).max() <= 0.5  # no face spans the image
    for name in ("globe.glb", "globe.gltf"):
        path = save_mesh(textured, tmp_path / name)
        data = path.read_bytes()
        if name.endswith(".glb"):
            data = data[20 : 20 + struct.unpack_from("<I", data, 12)[0]]
        tree = json.loads(data)
        (texture,) = tree["textures"]
        assert tree["samplers"][texture["sampler"]] == {"wrapS": 10497, "wrapT": 33071}


@needs_render
def test_a_globe_drape_renders_its_poles_in_their_own_colours():
    """The render of the test above: a camera over each pole, unlit, sees the pole's own colour at the middle of the
    picture (it saw the two poles' mean at the coarse mip levels of the pole triangles), and the antimeridian's
    faces (u past 1) still show the image's own colours (no smear across the whole image)."""
    from stepterrain.globe import drape_texture

    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    mesh = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=33, device="cpu").mesh()
    image = _two_pole_texture()
    textured = drape_texture(mesh, image)
    _assert_poles_show_their_own_colours(textured, image)


@needs_render
def test_a_globe_drape_read_back_keeps_its_sampler_and_its_poles(tmp_path):
    """trimesh's glTF reader ignores samplers: a globe drape's GLB read back (read_mesh) lost its wrap, rendered its
    poles blended with each other again and was written again without its sampler. read_mesh now gives the
    material the sampler's wrap modes (from the JSON it has read): the re-export keeps the sampler and the renders
    over the poles show each pole's own colour (the mean of the two before)."""
    import json
    import struct

    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.globe import drape_texture

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=17, device="cpu").mesh()
    image = _two_pole_texture()
    back = read_mesh(save_mesh(drape_texture(mesh, image), tmp_path / "globe.glb"))
    assert back.visual.material.wrap == ("REPEAT", "CLAMP_TO_EDGE")
    data = save_mesh(back, tmp_path / "again.glb").read_bytes()
    tree = json.loads(data[20 : 20 + struct.unpack_from("<I", data, 12)[0]])
    (texture,) = tree["textures"]
    assert tree["samplers"][texture["sampler"]] == {"wrapS": 10497, "wrapT": 33071}
    _assert_poles_show_their_own_colours(back, image)


def test_render_mesh_counts_a_globe_drape_s_widened_texture_against_the_budget(budget):
    """render_mesh counted a globe drape's texture at the image's size, then drew the picture _periodic_columns
    widens (the image's columns repeated over the UVs' u range and 256 columns beyond each side: a 256-column image
    drawn 1024 wide), past the budget; render_textured_mesh counted the widened one. Both refuse now."""
    from stepterrain.globe import drape_texture
    from stepterrain.render import _render_bytes, render_mesh, render_textured_mesh

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    textured = drape_texture(mesh, _two_pole_texture())
    image_only = _render_bytes(64, 64, texels=128 * 256, vertices=len(textured.vertices), faces=len(textured.faces))
    budget(image_only + 1024)
    for render in (render_mesh, render_textured_mesh):
        with pytest.raises(OutputTooLargeError, match=r"a 1024 x 128 texel texture"):
            render(textured, window_size=(64, 64))


@needs_render
def test_render_view_of_a_globe_drape_read_back_keeps_its_poles(tmp_path):
    """render_view draws a copy of the mesh in the view's frame; trimesh's PBRMaterial.copy drops the material's
    wrap, so a globe drape read back from its GLB (a PBR material) was drawn repeating v again: the pole blended with
    the other pole (75 levels off the drape's own render at the north pole). The copy keeps the wrap now."""
    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.globe import EARTH_RADIUS, drape_texture, look_from, render_view

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=17, device="cpu").mesh()
    textured = drape_texture(mesh, _two_pole_texture())
    back = read_mesh(save_mesh(textured, tmp_path / "globe.glb"))
    camera = look_from(90.0, 180.0, 3 * EARTH_RADIUS)
    drawn, again = (render_view(m, camera, window_size=(64, 64)).astype(int) for m in (textured, back))
    assert np.abs(drawn - again).max() <= 4


def _face_grids(meshes, cells):
    """(6, N + 1, N + 1, 3) float64 vertex positions and a (6, N + 1, N + 1) used mask from per_face meshes (their UV is
    the face-local (j, i) / N)."""
    positions = np.full((6, cells + 1, cells + 1, 3), np.nan)
    for f, face in enumerate(meshes):
        ij = np.rint(np.asarray(face.visual.uv) * cells).astype(int)
        positions[f, ij[:, 1], ij[:, 0]] = face.vertices
    return positions, ~np.isnan(positions[..., 0])


def _look_ahead_errors(positions, cells):
    """(6, N + 1, N + 1): each node's distance from the midpoint of the hypotenuse it splits (the cube corners 0), in
    NumPy on the given positions; the bisection of two right triangles per face split by the main diagonal."""
    n = cells + 1
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    s = (i | j) & -(i | j)
    s[0, 0] = cells
    odd_i, odd_j = (i // s) % 2 == 1, (j // s) % 2 == 1
    diagonal = odd_i & odd_j
    main = diagonal & (((i // s - 1) // 2 + (j // s - 1) // 2) % 2 == 0)
    di = np.where(odd_i, s, 0)
    dj = np.where(diagonal, np.where(main, s, -s), np.where(odd_j, s, 0))
    corner = np.isin(i, (0, cells)) & np.isin(j, (0, cells))
    errors = np.zeros((6, n, n))
    for f in range(6):
        p = positions[f]
        a = p[np.clip(i + di, 0, cells), np.clip(j + dj, 0, cells)]
        b = p[np.clip(i - di, 0, cells), np.clip(j - dj, 0, cells)]
        errors[f] = np.where(corner, 0.0, np.linalg.norm(p - 0.5 * (a + b), axis=-1))
    return errors


def test_the_geometric_error_bounds_the_meshs_own_float64_vertices():
    """The geometric error e was measured on the float32 node positions (0.25 m rounding at the earth's radius) while
    the mesh's vertices are float64 (R + z) · w / |w|: a node's error on those was up to 0.65 m above its saturated e
    at face size 1025 (6.52 m against 5.88 m), so ``mesh(error=6)`` left out nodes 6.52 m off the mesh. Every omitted
    node's look-ahead error, on the vertices the mesh itself is made of, stays within the requested error."""
    globe = Globe.sample(face_size=129, device="cpu")
    cells = globe.cells
    positions, used = _face_grids(globe.mesh(per_face=True), cells)
    assert used.all()
    exact = _look_ahead_errors(positions, cells)
    saturated = globe.node_parameters()["geometric_error"].astype(np.float64)
    assert (saturated >= exact).all(), float((exact - saturated).max())
    # the errors the float32 positions gave: requested errors between them and the exact ones
    rounded = _look_ahead_errors(globe.positions.astype(np.float64), cells)
    worst = np.argsort((exact - rounded).ravel())[-5:]
    errors = [*(0.5 * (exact.ravel()[worst] + rounded.ravel()[worst])), *np.quantile(exact, [0.3, 0.6, 0.9])]
    for error in errors:
        _, kept = _face_grids(globe.mesh(error=float(error), per_face=True), cells)
        assert exact[~kept].max() <= error, (error, float(exact[~kept].max()))


@wp.kernel
def _seam_look_ahead_errors(grid: cs.CubeSphereGrid, nodes: wp.array[wp.vec4i], out: wp.array2d[wp.float64]):
    """Per edge node (face, i, j, s) splitting its hypotenuse along the edge: the kernels' look-ahead error and the
    distance on the mesh's own vertices (:func:`cs.entry_position64`) in the planet frame."""
    q = nodes[wp.tid()]
    step = wp.vec2i(q[3], 0)
    if q[1] == 0 or q[1] == grid.cells:
        step = wp.vec2i(0, q[3])
    node = wp.vec2i(q[1], q[2])
    a = node + step
    b = node - step
    out[wp.tid(), 0] = cs.look_ahead_error(grid, q[0], q[1], q[2], a, b)
    v = cs.entry_position64(grid, cs.node_entry(grid.cells, 0, q[0], q[1], q[2]))
    pa = cs.entry_position64(grid, cs.node_entry(grid.cells, 0, q[0], a[0], a[1]))
    pb = cs.entry_position64(grid, cs.node_entry(grid.cells, 0, q[0], b[0], b[1]))
    out[wp.tid(), 1] = wp.length(v - wp.float64(0.5) * (pa + pb))


def _seam_copies(cells):
    """Entries of the face-edge nodes and, per entry, the index of its cube point (equal on the copies)."""
    n = cells + 1
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    edge = (i == 0) | (j == 0) | (i == cells) | (j == cells)
    local = np.stack([2 * j[edge] - cells, 2 * i[edge] - cells, np.full(int(edge.sum()), cells)], axis=1)
    points, entries = [], []
    for f, frame in enumerate(cs.FACE_FRAMES):
        point = np.empty_like(local)
        for k, axis in enumerate(frame):
            point[:, abs(axis) - 1] = np.sign(axis) * local[:, k]
        points.append(point)
        entries.append(f * n * n + i[edge] * n + j[edge])
    _, group = np.unique(np.concatenate(points), axis=0, return_inverse=True)
    return np.concatenate(entries), group.ravel()


def _differing_copies(values, group):
    """Indices of the values whose bits differ from their group's first value."""
    first = np.empty(group.max() + 1, dtype=values.dtype)
    first[group[::-1]] = values[::-1]
    bits = f"u{values.itemsize}"
    return np.flatnonzero(values.view(bits) != first[group].view(bits))


def test_the_copies_of_a_seam_node_have_the_same_parameter_bits(device):
    """Each copy of a seam node measured its look-ahead error e in its own face's frame, where the difference
    vector's components come as a signed permutation of the other copies'; summed in frame order (``wp.length``;
    CUDA's fused multiply-adds round order-dependently) the copies' e could part by a bit and, after
    e · (1 + 2^-22) rounds to float32, one side of the seam refine and the other not. The difference is now turned
    into the planet frame first: every copy's float64 e is the bits of the distance on the mesh's own vertices in
    the planet frame, and the saturated (e, r, h, α) of the copies are bit-identical on the embedded relief.
    (No differing pair of copies showed on the CPU before: there an edge node's difference has its two cube-normal
    components of equal magnitude, so the frame order did not matter without fused multiply-adds; the face-frame
    e did differ from the planet frame's by a bit.)"""
    for face_size in (129, 257):
        globe = Globe.sample(face_size=face_size, device=device)
        cells = globe.cells
        n = cells + 1
        entries, group = _seam_copies(cells)
        for name, values in globe.node_parameters().items():
            values = values.reshape(-1)[entries]
            assert _differing_copies(values, group).size == 0, (face_size, name)
        f, i, j = entries // (n * n), entries % (n * n) // n, entries % n
        along = np.where((i == 0) | (i == cells), j, i)
        inner = (along > 0) & (along < cells)  # the cube's corners split no hypotenuse
        nodes = np.stack([f, i, j, along & -along], axis=1)[inner].astype(np.int32)
        errors = wp.zeros((len(nodes), 2), dtype=wp.float64, device=device)
        wp.launch(_seam_look_ahead_errors, dim=len(nodes),
                  inputs=[globe._grid, wp.array(nodes, dtype=wp.vec4i, device=device)], outputs=[errors],
                  device=device)
        errors = errors.numpy()
        assert (errors[:, 0].view(np.uint64) == errors[:, 1].view(np.uint64)).all(), face_size
        assert _differing_copies(errors[:, 0].copy(), group[inner]).size == 0, face_size


def test_a_close_view_saved_by_the_library_is_stored_relative_to_its_eye(tmp_path):
    """``stepterrain globe`` wrote a view's GLB relative to the eye (``origin=camera.eye``), but a library user's
    ``save_mesh(globe.mesh(camera=...), "view.glb")`` stored it relative to the centre of the mesh's bounds, which
    spans thousands of km: the vertices under an eye 100 m up came back up to 0.3 m off. ``Globe.mesh`` now records
    the eye in ``metadata["eye"]`` and ``save_mesh`` takes it as the origin when none is given: each vertex within
    float32's rounding of its own distance from the eye. A mesh moved away from its recorded eye (scaled to km)
    keeps the centre of its bounds (the stale eye would round it far worse)."""
    from stepterrain.export import read_mesh, save_mesh

    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    z = 1000.0 * np.cos(np.radians(lat))[:, None] * np.sin(np.radians(3 * lon))[None, :]
    globe = Globe.from_latlon(z, lat, lon, face_size=65, device="cpu")
    camera = look_from(0.0, 0.0, 100.0 + globe._height_under(np.array([1.0, 0.0, 0.0])))
    mesh = globe.mesh(error=0.5, camera=camera)
    assert mesh.metadata["eye"] == list(camera.eye)
    exact = np.asarray(mesh.vertices)
    assert np.ptp(exact, axis=0).max() > 1e6  # the view's mesh spans thousands of km
    distance = np.linalg.norm(exact - np.asarray(camera.eye), axis=1)
    assert distance.min() < 10_000.0  # a vertex near the eye
    save_mesh(mesh, tmp_path / "view.glb")
    back = read_mesh(tmp_path / "view.glb")
    error = np.linalg.norm(back.vertices - exact, axis=1)
    assert (error <= 2.0**-23 * (distance + 2.0)).all(), float((error / distance).max())
    assert back.metadata["eye"] == list(camera.eye)  # read back: saved again, the same origin
    # shared_bounds (a set of meshes stored alike) keep their translation, the floor of their centre: rounded there
    save_mesh(mesh, tmp_path / "shared.glb", shared_bounds=mesh.bounds)
    shared = np.linalg.norm(read_mesh(tmp_path / "shared.glb").vertices - exact, axis=1)
    assert (shared > 2.0**-23 * (distance + 2.0)).any()  # not within the eye's rounding everywhere
    # scaled to km, the recorded eye lies 6,000 km from a mesh 13,000 m across: the bounds' centre is kept
    km = mesh.copy()
    km.apply_scale(1e-3)
    save_mesh(km, tmp_path / "km.glb")
    scale = np.abs(km.vertices).max()
    assert np.abs(read_mesh(tmp_path / "km.glb").vertices - km.vertices).max() <= 2.0**-23 * scale


def test_a_globe_drape_leaves_no_vertex_unused_and_reads_back_with_its_counts(tmp_path):
    """drape_texture gives each pole corner a copy of its own (one per face) but kept the pole vertex itself, which no
    face used any more: two stray vertices in every drape of a whole globe, written into the GLB (``stepterrain info``
    counted them) and dropped by trimesh's OBJ reader, so the GLB read back with two vertices more than the OBJ of
    the same mesh. The pole vertex now serves its first face (every vertex a face's corner), and GLB, glTF and OBJ
    read back with the mesh's counts; the surface is the same, the mesh's vertices at their indices."""
    from stepterrain.export import read_mesh, save_mesh
    from stepterrain.globe import drape_texture

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh()
    textured = drape_texture(mesh, _two_pole_texture())
    used = np.zeros(len(textured.vertices), dtype=bool)
    used[textured.faces] = True
    assert used.all(), f"{(~used).sum()} vertices no face uses"
    assert np.array_equal(textured.vertices[textured.faces], mesh.vertices[mesh.faces])  # the same faces, in order
    assert np.array_equal(textured.vertices[: len(mesh.vertices)], mesh.vertices)  # the mesh's vertices kept in place
    uv = textured.visual.uv[textured.faces]
    assert ((uv >= 0) & (uv[..., 1] <= 1)[..., None]).all() and (uv[..., 0] <= 2).all()
    for suffix in (".glb", ".gltf", ".obj"):
        back = read_mesh(save_mesh(textured, tmp_path / f"globe{suffix}"))
        assert (len(back.vertices), len(back.faces)) == (len(textured.vertices), len(textured.faces)), suffix


def test_a_camera_looking_straight_down_at_a_pole_names_its_view_direction_as_numbers():
    """Camera(eye over the north pole, target the centre) with the default up (0, 0, 1): the refusal printed the view
    direction as "(np.float64(0.0), np.float64(0.0), np.float64(-20000000.0))" (NumPy 2 reprs) and said nothing of
    what up to give."""
    with pytest.raises(InvalidInputError) as caught:
        Camera(eye=(0.0, 0.0, 2.0e7), target=(0.0, 0.0, 0.0))
    message = str(caught.value)
    assert "np.float64" not in message
    assert "view direction (0.0, 0.0, -20000000.0)" in message and "up=(1, 0, 0)" in message
    Camera(eye=(0.0, 0.0, 2.0e7), target=(0.0, 0.0, 0.0), up=(1.0, 0.0, 0.0))  # the up it suggests is taken


@pytest.mark.parametrize("target", [(5.0, 0.0, 0.0), (0.0, -3.0, 0.0), (1.0, 1.0, 1.0)])
def test_the_up_a_camera_refusal_suggests_is_taken(target):
    """The refusal of an up along the view direction suggested up=(1, 0, 0) whatever the view: for a view along x, the
    very up it had refused. It suggests the axis least along the view direction now, which is taken."""
    with pytest.raises(InvalidInputError) as caught:
        Camera(eye=(0.0, 0.0, 0.0), target=target, up=target)
    suggested = re.search(r"up=\((\d), (\d), (\d)\)", str(caught.value))
    assert suggested is not None, str(caught.value)
    Camera(eye=(0.0, 0.0, 0.0), target=target, up=tuple(float(k) for k in suggested.groups()))


def _seam_pairs(parts):
    """(a, b, pairs) for each two per-face meshes a < b sharing vertices: pairs[:, 0] indexes a's copies of the
    shared vertices, pairs[:, 1] b's (the same float64 positions)."""
    for a in range(len(parts)):
        index = {tuple(v): i for i, v in enumerate(parts[a].vertices)}
        for b in range(a + 1, len(parts)):
            pairs = np.array([(index[tuple(v)], j) for j, v in enumerate(parts[b].vertices) if tuple(v) in index])
            if len(pairs):
                yield a, b, pairs


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("view", [None, (30.0, 10.0, 2.0e7)])
def test_the_six_per_face_meshes_written_one_by_one_keep_their_seams_welded(tmp_path, ext, view):
    """Globe.mesh(per_face=True) gives one mesh per cube face (paper 003 §5.3: a texture per face), naturally written to
    six files. Each glTF stored its float32 positions about its own centre (or, with a camera, about the eye for the
    faces near it and its own centre for the far ones), so the two copies of a seam vertex rounded apart by up to
    0.25 m on the Earth: cracks along the cube edges where the files met in a viewer. They are stored by the whole
    mesh's bounds now (recorded as metadata["shared_bounds"]), alike in every file: the copies read back identical."""
    from stepterrain.export import read_mesh, save_mesh

    globe = Globe.sample(face_size=33, device="cpu")
    camera = None if view is None else look_from(*view)
    parts = globe.mesh(error=100.0, camera=camera, per_face=True, cull=False)
    back = [read_mesh(save_mesh(part, tmp_path / f"face{k}{ext}")) for k, part in enumerate(parts)]
    seams = 0
    for a, b, pairs in _seam_pairs(parts):
        seams += len(pairs)
        np.testing.assert_array_equal(back[a].vertices[pairs[:, 0]], back[b].vertices[pairs[:, 1]])
    assert seams > 100  # every cube edge is some face pair's seam
    # each face as finely as the whole mesh in one file (float32 about its centre, or about a camera's eye)
    whole = globe.mesh(error=100.0, camera=camera, cull=False)
    rounding = np.abs(read_mesh(save_mesh(whole, tmp_path / f"whole{ext}")).vertices - whole.vertices).max()
    assert 0 < max(np.abs(read.vertices - part.vertices).max() for part, read in zip(parts, back, strict=True)) \
        <= rounding


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
@pytest.mark.parametrize("view", [(0.0, 45.0, 3.0e6, 30.0), (0.0, 45.0, 3.0e7, 8.0)])
def test_the_culled_per_face_meshes_written_one_by_one_keep_their_seams_welded(tmp_path, ext, view):
    """A view culls the faces it does not see, leaving some per-face meshes a few triangles of their face. save_mesh
    stored those by their own bounds (the shared ones reach more than twice as far: the rule for a piece cut from a
    part), the others by the shared bounds, or about the eye they hold: the copies of a seam vertex read back up to
    0.5 m apart from an eye 3,000 km up (8 triangles about their own centre, 934 about the eye), 6 cm from one 30,000 km
    up (the eye beyond the bounds, a culled face about its own centre). Each part records its counts and bounds as
    made (metadata["whole_part"]) and keeps the shared frame whatever culling left of it."""
    from stepterrain.export import read_mesh, save_mesh

    globe = Globe.sample(face_size=33, device="cpu")
    latitude, longitude, altitude, fov = view
    camera = look_from(latitude, longitude, altitude, fov=math.radians(fov))
    parts = globe.mesh(error=300.0, camera=camera, per_face=True)
    full = globe.mesh(error=300.0, camera=camera, per_face=True, cull=False)
    culled = [k for k, part in enumerate(parts) if 0 < len(part.faces) < len(full[k].faces)]
    assert culled  # culling left some face part of its triangles
    back = [read_mesh(save_mesh(part, tmp_path / f"face{k}{ext}")) for k, part in enumerate(parts)]
    seams = 0
    for a, b, pairs in _seam_pairs(parts):
        if a in culled or b in culled:
            seams += len(pairs)
        np.testing.assert_array_equal(back[a].vertices[pairs[:, 0]], back[b].vertices[pairs[:, 1]],
                                      err_msg=f"faces {a} and {b}")
    assert seams > 0  # a seam of a culled face is checked
    whole = globe.mesh(error=300.0, camera=camera)  # each part as finely as the whole view in one file
    rounding = np.abs(read_mesh(save_mesh(whole, tmp_path / f"whole{ext}")).vertices - whole.vertices).max()
    assert max(np.abs(read.vertices - part.vertices).max() for part, read in zip(parts, back, strict=True)
               if len(part.vertices)) <= rounding


def test_the_per_face_meshes_carry_their_uvs_without_a_made_up_texture(tmp_path):
    """Globe.mesh(per_face=True) gave each face TextureVisuals(uv=uv) without an image, so trimesh filled in its
    placeholder material: a 2 x 2 grey (100, 100, 100) image. The GLB embedded it as the base colour texture and the
    OBJ wrote it as a side image with Kd 0.4: viewers showed the faces nearly black where the whole mesh is white, and
    render_view drew them grey (84 against 184 for the whole mesh). The UVs stay (for a texture per face, §5.3) with a
    plain matte material, as the whole mesh's."""
    import json
    import struct

    from stepterrain.export import save_mesh

    globe = Globe.sample(face_size=9, device="cpu")
    part = globe.mesh(error=0.0, per_face=True)[1]
    assert part.visual.uv.shape == (len(part.vertices), 2)
    data = save_mesh(part, tmp_path / "face.glb").read_bytes()
    tree = json.loads(data[20 : 20 + struct.unpack("<I", data[12:16])[0]])
    assert "images" not in tree and "textures" not in tree
    (material,) = tree["materials"]
    assert material["pbrMetallicRoughness"].get("baseColorFactor", [1.0] * 4) == [1.0] * 4
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    save_mesh(part, tmp_path / "face.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["face.glb", "face.mtl", "face.obj"]  # no image made up
    kd = [line.split()[1:] for line in (tmp_path / "face.mtl").read_text().splitlines() if line.startswith("Kd")]
    assert kd == [["1.00000000"] * 3]


@needs_render
def test_a_per_face_mesh_renders_in_the_colours_of_the_whole_mesh():
    globe = Globe.sample(face_size=9, device="cpu")
    camera = look_from(0.0, 0.0, 2.0e7)  # straight over cube face 1's centre (+x)
    part = render_view(globe.mesh(error=0.0, per_face=True)[1], camera, window_size=(64, 40))
    whole = render_view(globe.mesh(error=0.0), camera, window_size=(64, 40))
    np.testing.assert_allclose(part[15:25, 25:40].astype(float).mean(), whole[15:25, 25:40].astype(float).mean(),
                               atol=2.0)


def test_a_piece_of_a_per_face_mesh_is_stored_about_its_own_centre(tmp_path):
    """trimesh copies metadata into a piece cut from a mesh (``submesh``, ``update_faces``) and into one transformed, so
    a piece of a per-face mesh, or one shrunk about its own centre, still records the whole globe's shared bounds and
    lies within them: stored about the globe's centre, a 320 km triangle's GLB rounded by 0.19 m instead of 7.5 mm, a
    9 km mesh's by 0.25 m instead of 0.24 mm. The recorded bounds decide only while they round at most one binary order
    coarser than the mesh's own; the six whole faces keep them (the weld test above)."""
    import trimesh

    from stepterrain.export import read_mesh, save_mesh

    face = Globe.sample(face_size=33, device="cpu").mesh(error=100.0, per_face=True, cull=False)[1]
    shrunk = face.copy()
    shrunk.apply_transform(trimesh.transformations.scale_matrix(1e-3, origin=face.vertices.mean(axis=0)))
    for name, piece in (("triangle", face.submesh([np.arange(1)], append=True)), ("shrunk", shrunk)):
        assert piece.metadata["shared_bounds"] == face.metadata["shared_bounds"]
        alone = piece.copy()
        del alone.metadata["shared_bounds"]
        back = read_mesh(save_mesh(piece, tmp_path / f"{name}.glb")).vertices
        np.testing.assert_array_equal(back, read_mesh(save_mesh(alone, tmp_path / f"{name}_alone.glb")).vertices)
        extent = float(np.ptp(piece.vertices, axis=0).max())
        assert np.abs(back - piece.vertices).max() <= extent * 2.0**-24 + 1e-9, name  # float32 about its own centre


def test_the_six_per_face_meshes_concatenate_with_their_plain_material(tmp_path):
    """trimesh.util.concatenate(parts) (the six faces in one mesh again) packed six materials of different names into a
    texture atlas: transparent padding (the GLB alphaMode MASK, single-sided) and grey texels (trimesh's colour for an
    unset base colour). Alike, they are kept as one white material without an image (the OBJ's matte Ks 0 too)."""
    import json
    import struct

    import trimesh

    from stepterrain.export import save_mesh

    parts = Globe.sample(face_size=9, device="cpu").mesh(error=0.0, per_face=True)
    whole = trimesh.util.concatenate(parts)
    assert whole.visual.uv.shape == (len(whole.vertices), 2)
    data = save_mesh(whole, tmp_path / "whole.glb").read_bytes()
    save_mesh(parts[2], tmp_path / "face.obj")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["face.mtl", "face.obj", "whole.glb"]
    assert [line for line in (tmp_path / "face.mtl").read_text().splitlines() if line[:2] in ("Kd", "Ks")] == [
        "Kd 1.00000000 1.00000000 1.00000000", "Ks 0.00000000 0.00000000 0.00000000"]
    tree = json.loads(data[20 : 20 + struct.unpack("<I", data[12:16])[0]])
    assert "images" not in tree and "textures" not in tree
    (material,) = tree["materials"]
    assert material["pbrMetallicRoughness"].get("baseColorFactor", [1.0] * 4) == [1.0] * 4
    assert material["doubleSided"] is True and material.get("alphaMode", "OPAQUE") == "OPAQUE"
    parts[0].visual.material.baseColorFactor = (255, 0, 0, 255)  # each face its own material: the others stay white
    assert [p.visual.material.baseColorFactor for p in parts[1:]] == [None] * 5


@pytest.mark.parametrize("altitude", [-2 * EARTH_RADIUS - 10_000.0, -EARTH_RADIUS])
def test_look_from_refuses_an_eye_at_or_beyond_the_centre(altitude):
    """look_from put the eye at (radius + altitude) · outward: an altitude below -radius turned it through the centre,
    and look_from(0, 0, -2R - 10 km) was a camera 10 km above the antipode (0°, 180°) looking up into space, which
    Globe.mesh took and clipped to an empty mesh without a word. An eye at or beyond the centre is refused by name;
    one below the sphere above the centre (under the Dead Sea) is still a camera."""
    with pytest.raises(InvalidInputError, match=r"^altitude must be more than -radius .*; got "):
        look_from(0.0, 0.0, altitude)
    below = look_from(31.5, 35.5, -400.0)  # the Dead Sea's shore lies 430 m below the sphere
    assert np.linalg.norm(below.eye) == pytest.approx(EARTH_RADIUS - 400.0)


@pytest.mark.parametrize("option, value", [("--error", "-1"), ("--face-size", "1000"), ("--exaggeration", "0"),
                                           ("--radius", "-6371000")])
def test_the_cli_refuses_a_bad_number_before_loading_the_grid(tmp_path, capsys, monkeypatch, option, value):
    """``stepterrain globe`` refused a negative --error only after it had loaded the grid and built the hierarchy
    (Globe.mesh checks it), and a --face-size that is not 2^k + 1, a --exaggeration or --radius <= 0 after loading the
    grid (Globe.from_latlon): with a large GeoTIFF or --face-size 4097, seconds to minutes of work for a typo. They
    are refused first now, in the library's words with the option named; the grid is never read."""
    from stepterrain import _cli_globe
    from stepterrain.cli import main

    def loaded(*args, **kwargs):
        raise AssertionError("the grid was loaded before the option was checked")

    monkeypatch.setattr(_cli_globe, "_load_grid", loaded)
    monkeypatch.setattr("stepterrain.globe.load_global_relief", loaded)
    grid = tmp_path / "grid.npz"
    np.savez(grid, elevation=np.zeros((18, 36)), lat=np.arange(85, -90, -10.0), lon=np.arange(-175, 180, 10.0))
    out = tmp_path / "g.ply"
    for source in ([str(grid)], []):
        assert main(["-q", "globe", *source, option, value, "-o", str(out), "--device", "cpu"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"stepterrain globe: error: {option} must ") and value in err, err
        assert not out.exists()


def test_a_globe_drape_saved_as_obj_shows_its_texture_at_full_brightness_and_matte(tmp_path):
    """drape_texture's TextureVisuals(uv=..., image=...) is trimesh's SimpleMaterial (Kd 0.4, Ks 0.4 by default).
    save_mesh wrote it to glTF white and matte, but its .mtl kept Kd 0.4 and Ks 0.4 (only a PBR material's MTL was made
    white): the MTL model multiplies map_Kd by Kd (three.js's MTLLoader does), so ``stepterrain globe --texture
    bluemarble.jpg -o globe.obj`` showed the earth at 40 % brightness, and shiny. The MTL now says Kd 1, Ks 0, as the
    glTF's material; the mesh's own material is left as it was."""
    from stepterrain.export import save_mesh
    from stepterrain.globe import drape_texture

    lat, lon = np.arange(85, -90, -10.0), np.arange(-175, 180, 10.0)
    globe = Globe.from_latlon(np.zeros((lat.size, lon.size)), lat, lon, face_size=5, device="cpu")
    image = np.random.default_rng(3).integers(0, 256, (16, 32, 3), dtype=np.uint8)
    draped = drape_texture(globe.mesh(), image)
    diffuse = np.array(draped.visual.material.diffuse)
    save_mesh(draped, tmp_path / "globe.obj")
    lines = {line.split()[0]: [float(v) for v in line.split()[1:]]
             for line in (tmp_path / "globe.mtl").read_text().splitlines() if line[:3] in ("Kd ", "Ks ")}
    assert lines == {"Kd": [1.0, 1.0, 1.0], "Ks": [0.0, 0.0, 0.0]}
    np.testing.assert_array_equal(draped.visual.material.diffuse, diffuse)  # the caller's mesh untouched


def test_a_georeferenced_texture_is_draped_where_its_georeferencing_puts_it(tmp_path, monkeypatch):
    """A texture file was draped as a plate-carrée image from 180° W whatever its georeferencing said: a global
    GeoTIFF in longitudes 0..360 came out half a turn round, and a UTM orthophoto (or a regional one in degrees)
    was wrapped round the whole earth, without a word. A global one in degrees is put at -180..180 now; any other
    georeferencing is refused by name. A texture without georeferencing is plate carrée from 180° W, as before.
    The GeoTIFF tags and world files are read without rasterio (the optional [geo] extra; the files are written with
    it here, read with it hidden)."""
    rasterio = pytest.importorskip("rasterio")
    from PIL import Image
    from rasterio.transform import Affine

    from stepterrain.globe import _texture_pixels, drape_colors

    pixels = np.zeros((18, 36, 3), np.uint8)
    pixels[:, 18:, 0] = 255  # red east of Greenwich, in -180..180 columns

    def geotiff(name, data, transform, crs="EPSG:4326", **tags):
        with rasterio.open(tmp_path / name, "w", driver="GTiff", width=data.shape[1], height=data.shape[0], count=3,
                           dtype="uint8", crs=crs, transform=transform) as ds:  # fmt: skip
            ds.update_tags(**tags)
            ds.write(np.moveaxis(data, 2, 0))
        return tmp_path / name

    def png(name, data, world, prj=None):  # a world file: A, D, B, E, then the upper-left pixel's centre C, F
        Image.fromarray(data).save(tmp_path / name)
        (tmp_path / name).with_suffix(".pgw").write_text("\n".join(map(str, world)) + "\n")
        if prj:
            (tmp_path / name).with_suffix(".prj").write_text(prj)
        return tmp_path / name

    directions = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 0.5], [-1.0, -1.0, -0.5]]) * EARTH_RADIUS
    expected = drape_colors(directions, pixels)
    assert expected[:, 0].tolist() == [255, 0, 255, 0]  # 90° E and 45° E red, 90° W and 135° W not
    east = geotiff("east.tif", np.roll(pixels, 18, axis=1), Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0))  # 0..360
    west = geotiff("west.tif", pixels, Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0))
    # PixelIsPoint: its tiepoint at the first pixel's centre (15 E), its west edge at 10 E (19 columns, not 19.5)
    point = geotiff("point.tif", np.roll(pixels, 17, axis=1), Affine(10.0, 0.0, 10.0, 0.0, -10.0, 90.0),
                    AREA_OR_POINT="Point")
    world_east = png("east.png", np.roll(pixels, 18, axis=1), (10, 0, 0, -10, 5, 85))
    refused = [geotiff("utm.tif", pixels, Affine(10.0, 0.0, 376000.0, 0.0, -10.0, 3807000.0), "EPSG:32611"),
               geotiff("alps.tif", pixels, Affine(0.1, 0.0, 5.0, 0.0, -0.1, 48.0)),
               geotiff("south_up.tif", pixels, Affine(10.0, 0.0, -180.0, 0.0, 10.0, -90.0)),
               geotiff("rotated.tif", pixels, Affine(10.0, 0.01, -180.0, 0.0, -10.0, 90.0)),  # ModelTransformation
               png("alps.png", pixels, (0.1, 0, 0, -0.1, 5.05, 47.95)),
               png("utm.png", pixels, (10, 0, 0, -10, -175, 85), prj='PROJCS["WGS 84 / UTM zone 11N",GEOGCS[...]]')]
    with monkeypatch.context() as hidden:
        hidden.setitem(sys.modules, "rasterio", None)  # import rasterio raises ImportError
        for placed in (east, west, point, world_east):
            np.testing.assert_array_equal(drape_colors(directions, placed), expected, err_msg=str(placed))
            np.testing.assert_array_equal(_texture_pixels(placed), pixels, err_msg=str(placed))  # each column
        for name in refused:
            with pytest.raises(InvalidInputError, match=r"^texture .* must be a global plate-carrée image"):
                drape_colors(directions, name)


def test_a_texture_with_an_upper_case_extension_finds_its_lower_case_world_file(tmp_path):
    """GDAL looks for the world file of ``ALPS.PNG`` as ``ALPS.pgw`` (the extension's first and last letters and "w",
    lower case first, then ``ALPS.PGW``): the globe looked for ``ALPS.PGw``, so a regional image whose ``.pgw`` said
    so was draped round the whole earth from 180° W, without a word; it is refused by name now, as ``alps.png`` is."""
    from PIL import Image

    from stepterrain.globe import drape_colors

    directions = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]) * EARTH_RADIUS
    for name in ("alps.png", "ALPS.PNG"):
        Image.fromarray(np.zeros((18, 36, 3), np.uint8)).save(tmp_path / name, format="PNG")
        (tmp_path / name).with_suffix(".pgw").write_text("0.1\n0\n0\n-0.1\n5.05\n47.95\n")
        with pytest.raises(InvalidInputError, match=r"must be a global plate-carrée image .* world file "
                                                    r"'(alps|ALPS)\.pgw'"):
            drape_colors(directions, tmp_path / name)


def test_a_texture_file_over_the_memory_budget_is_refused_before_it_is_decoded(budget, tmp_path, capsys, monkeypatch):
    """The globe's texture files were decoded whole whatever the memory budget (an 8000 x 4000 JPEG: 96 MB of pixels,
    and 500 MB peak for the drape, under ``--memory-budget 10MB``), while the texture command's image read checks its
    pixels first (texture_lod's _check_read_budget). drape_colors and drape_texture refuse a file whose (H, W, 3|4)
    pixels exceed the budget (counted as a raster read: _check_read_budget), from its header, before decoding it;
    ``stepterrain globe --texture`` exits 2 naming it and --memory-budget, before the globe is built. Within the
    budget it drapes as before."""
    from PIL import Image

    import stepterrain.globe as globe
    from stepterrain.cli import main
    from stepterrain.globe import drape_colors, drape_texture

    picture = tmp_path / "earth.png"
    Image.fromarray(np.zeros((100, 200, 3), np.uint8)).save(picture)
    vertices = np.array([[EARTH_RADIUS, 0.0, 0.0]])
    decoded = []
    real_decode = globe.picture_uint8
    monkeypatch.setattr(globe, "picture_uint8", lambda *a, **k: decoded.append(1) or real_decode(*a, **k))
    need = 4 * 3 * 100 * 200  # its RGB cells as a raster read counts them (at least 4 bytes a cell: the drape's peak
    budget(need - 1)  # is several times its pixels)
    message = re.escape(f"reading {str(picture)!r} (the texture: 3 x 100 x 200 cells of uint8)")
    for drape in (drape_colors, lambda _, image: drape_texture(trimesh_sphere(), image)):
        with pytest.raises(OutputTooLargeError, match=message):
            drape(vertices, picture)
    assert not decoded  # refused from the header
    budget(need)
    assert drape_colors(vertices, picture).shape == (1, 4) and decoded

    def built(*args, **kwargs):
        raise AssertionError("the globe was built before the texture's budget was checked")

    monkeypatch.setattr(globe.Globe, "from_latlon", built)
    out = tmp_path / "g.ply"
    code = main(["-q", "globe", "--face-size", "9", "--texture", str(picture), "-o", str(out),
                 "--memory-budget", str(need - 1), "--device", "cpu"])
    err = capsys.readouterr().err
    assert code == 2 and "the texture: 3 x 100 x 200 cells of uint8" in err and "--memory-budget" in err, err
    assert not out.exists()


def trimesh_sphere():
    import trimesh

    return trimesh.creation.icosphere(subdivisions=1, radius=EARTH_RADIUS)


def test_a_texture_georeferenced_by_its_aux_xml_is_draped_where_it_says_or_refused(tmp_path, capsys):
    """GDAL writes a PNG's or JPEG's georeferencing into its PAM file, ``earth.png.aux.xml`` (``gdal_translate -of PNG``
    writes no world file), and reads it back first. The globe read GeoTIFF tags and world files only: a regional PNG
    or JPEG georeferenced so (an orthophoto of the Alps), a projected one, and a global one in longitudes 0..360 were
    all draped round the whole earth from 180° W without a word (the last half a turn off), as GeoTIFFs were before.
    Its geotransform and SRS are read now (the files written by GDAL through rasterio): the global one is put at
    -180..180, the others refused by name (drape_colors, drape_texture and ``stepterrain globe --texture``). An
    identity geotransform is GDAL's "none": the image stays plate carrée from 180° W."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.cli import main
    from stepterrain.globe import _texture_pixels, drape_colors, drape_texture

    pixels = np.zeros((18, 36, 3), np.uint8)
    pixels[:, 18:, 0] = 255  # red east of Greenwich, in -180..180 columns

    def picture(name, data, transform, crs="EPSG:4326"):
        path = tmp_path / name
        with warnings.catch_warnings():  # "not a GeoTIFF" (the PNG and JPEG drivers keep it in the .aux.xml)
            warnings.simplefilter("ignore")
            with rasterio.open(path, "w", driver="PNG" if name.endswith(".png") else "JPEG", width=data.shape[1],
                               height=data.shape[0], count=3, dtype="uint8", crs=crs, transform=transform) as ds:
                ds.write(np.moveaxis(data, 2, 0))
        assert (tmp_path / f"{name}.aux.xml").is_file() and not path.with_suffix(".pgw").exists()
        return path

    directions = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 0.5], [-1.0, -1.0, -0.5]]) * EARTH_RADIUS
    expected = drape_colors(directions, pixels)
    east = picture("east.png", np.roll(pixels, 18, axis=1), Affine(10.0, 0.0, 0.0, 0.0, -10.0, 90.0))  # 0..360
    np.testing.assert_array_equal(_texture_pixels(east), pixels)
    np.testing.assert_array_equal(drape_colors(directions, east), expected)
    plain = picture("plain.png", pixels, Affine.identity())  # GDAL's default geotransform: no georeferencing
    np.testing.assert_array_equal(drape_colors(directions, plain), expected)
    alps = picture("alps.png", pixels, Affine(0.1, 0.0, 5.0, 0.0, -0.1, 48.0))
    alps_jpeg = picture("alps.jpg", pixels, Affine(0.1, 0.0, 5.0, 0.0, -0.1, 48.0))
    utm = picture("utm.png", pixels, Affine(10.0, 0.0, 376000.0, 0.0, -10.0, 3807000.0), "EPSG:32611")
    for path, why in ((alps, "over longitudes 5 to 8.6 and latitudes 46.2 to 48"),
                      (alps_jpeg, "over longitudes 5 to 8.6 and latitudes 46.2 to 48"), (utm, "in a projected CRS")):
        aux = f"{path.name}.aux.xml"
        for drape in (drape_colors, lambda _, image: drape_texture(trimesh_sphere(), image)):
            with pytest.raises(InvalidInputError, match=r"^texture .* must be a global plate-carrée image"
                                                        rf".*got a PAM file {re.escape(repr(aux))} {why}"):
                drape(directions, path)
        out = tmp_path / "g.ply"
        assert main(["-q", "globe", "--face-size", "9", "--texture", str(path), "-o", str(out), "--device", "cpu"]) == 2
        assert "must be a global plate-carrée image" in capsys.readouterr().err and not out.exists()


def test_a_world_file_texture_takes_its_crs_from_the_aux_xml_beside_it(tmp_path):
    """``gdal_translate -of PNG -co WORLDFILE=YES`` writes the world file (``utm.wld``) and puts the CRS in the PAM
    file (``utm.png.aux.xml``), not in a ``.prj``. The globe read a world file's CRS from a ``.prj`` alone: a UTM
    image was refused as a regional one "over longitudes 376000 to 376360 and latitudes 3.80682e+06 to 3.807e+06",
    metres named as degrees. It is named as projected now, with the reprojection to run."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.globe import drape_colors

    path = tmp_path / "utm.png"
    with warnings.catch_warnings():  # "not a GeoTIFF"
        warnings.simplefilter("ignore")
        with rasterio.open(path, "w", driver="PNG", width=36, height=18, count=3, dtype="uint8", crs="EPSG:32611",
                           transform=Affine(10.0, 0.0, 376000.0, 0.0, -10.0, 3807000.0), WORLDFILE="YES") as ds:
            ds.write(np.zeros((3, 18, 36), np.uint8))
    assert (tmp_path / "utm.wld").is_file() and not (tmp_path / "utm.prj").exists()
    assert "<GeoTransform>" not in (tmp_path / "utm.png.aux.xml").read_text()  # its CRS alone
    with pytest.raises(InvalidInputError, match=r"got a world file 'utm\.wld' in a projected CRS: reproject it"):
        drape_colors(np.array([[EARTH_RADIUS, 0.0, 0.0]]), path)


def test_a_geotiff_texture_is_placed_by_its_aux_xml_before_its_tags_as_gdal_reads_it(tmp_path):
    """GDAL reads a GeoTIFF's georeferencing from its PAM file (``earth.tif.aux.xml``, where GDAL writes a
    geotransform set on a file opened read-only) before its own tags (GDAL_GEOREF_SOURCES: PAM, then INTERNAL), as
    rasterio, load_dem and the texture command read it. The globe read the tags first: a GeoTIFF whose tags say a
    regional extent and whose .aux.xml the whole globe was refused as regional, and one whose .aux.xml puts it in
    0..360 was draped half a turn off. Now its .aux.xml comes first; its tags' CRS still says whether it is
    projected when the .aux.xml names none."""
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import Affine

    from stepterrain.globe import _texture_pixels, drape_colors

    pixels = np.zeros((18, 36, 3), np.uint8)
    pixels[:, 18:, 0] = 255  # red east of Greenwich, in -180..180 columns
    directions = np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [1.0, 1.0, 0.5], [-1.0, -1.0, -0.5]]) * EARTH_RADIUS
    expected = drape_colors(directions, pixels)

    def geotiff(name, data, tags, crs, aux):
        path = tmp_path / name
        with rasterio.open(path, "w", driver="GTiff", width=36, height=18, count=3, dtype="uint8", crs=crs,
                           transform=tags) as ds:
            ds.write(np.moveaxis(data, 2, 0))
        (tmp_path / f"{name}.aux.xml").write_text(f"<PAMDataset><GeoTransform>{', '.join(map(str, aux))}"
                                                  "</GeoTransform></PAMDataset>")
        with rasterio.open(path) as ds:  # GDAL's own reading: the PAM file's geotransform, not the tags'
            assert ds.transform.to_gdal() == aux
        return path

    regional = Affine(0.1, 0.0, 5.0, 0.0, -0.1, 48.0)
    world = geotiff("world.tif", pixels, regional, "EPSG:4326", (-180.0, 10.0, 0.0, 90.0, 0.0, -10.0))
    np.testing.assert_array_equal(drape_colors(directions, world), expected)
    east = geotiff("east.tif", np.roll(pixels, 18, axis=1), Affine(10.0, 0.0, -180.0, 0.0, -10.0, 90.0), "EPSG:4326",
                   (0.0, 10.0, 0.0, 90.0, 0.0, -10.0))
    np.testing.assert_array_equal(_texture_pixels(east), pixels)
    utm = geotiff("utm.tif", pixels, Affine(10.0, 0.0, 376000.0, 0.0, -10.0, 3807000.0), "EPSG:32611",
                  (376000.0, 10.0, 0.0, 3807000.0, 0.0, -10.0))
    with pytest.raises(InvalidInputError, match=r"got a PAM file 'utm\.tif\.aux\.xml' in a projected CRS"):
        drape_colors(directions, utm)


@pytest.mark.parametrize(("dtype", "void"), [(np.int16, -32768), (np.float32, -9999)])
def test_the_cli_warns_of_undeclared_void_values_of_a_global_npz_as_load_dem_does(tmp_path, capsys, dtype, void):
    """A global .npz's cells of -32768 (int16's lowest) or -9999 (a common nodata value) far below its other heights,
    with no 'nodata' declaring them, were meshed as pits 10 to 33 km deep without a word, while the same cells of a
    raster INPUT (read by load_dem) and of every other subcommand's DEM are warned of. They are warned of now, naming
    the value and --nodata; once declared they are refused as missing, and a grid without them does not warn."""
    from stepterrain.cli import main

    elevation = np.full((180, 360), 100, dtype)
    elevation[::2] = 500
    elevation[3, 7] = elevation[100, 200] = void
    grid, out = tmp_path / "grid.npz", tmp_path / "g.ply"
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1)
    argv = ["globe", str(grid), "--face-size", "9", "--no-camera", "-o", str(out), "--device", "cpu", "-q"]
    assert main(argv) == 0 and out.exists()
    err = capsys.readouterr().err
    assert f"warning: grid.npz: 2 cells of 'elevation' hold {void}" in err and f"--nodata {void}" in err, err
    assert main([*argv, f"--nodata={void}"]) == 2
    assert "'elevation' has 2 nodata cells" in capsys.readouterr().err
    elevation[elevation == void] = 0
    np.savez(grid, elevation=elevation, lat=LAT1, lon=LON1)
    assert main(argv) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_radius_below_float32s_normal_range_is_refused_and_the_smallest_taken_meshes_as_radius_1():
    """The bounding shapes and metrics (paper 003 §6-§7) read the float32 node positions: radius 1e-50 made them all
    0 (every node at the centre, the cones' axes 0 / 0), and the clip test kept the whole globe in view (at face size
    9, 768 triangles where 120 are in it) without a word; a subnormal radius (1e-41) gave another mesh (466 triangles
    where radius 1 gives 468). Refused now, naming the radius; the smallest radius taken, float32's smallest normal,
    meshes as radius 1 does (the same faces, vertices to scale)."""
    lat, lon = np.linspace(85.0, -85.0, 18), np.linspace(-175.0, 175.0, 36)
    z = np.random.default_rng(0).uniform(-0.3, 0.3, (18, 36))
    for radius in (1e-50, 1e-41):
        with pytest.raises(InvalidInputError, match=r"^radius must be at least 1\.18e-38 m \(a normal float32, as the "
                                                     r"node positions are stored\); got 1e-(50|41)$"):
            Globe.from_latlon(z * radius, lat, lon, face_size=17, radius=radius, device="cpu")
    meshes = []
    for radius in (1.0, float(np.finfo(np.float32).tiny)):
        g = Globe.from_latlon(z * radius, lat, lon, face_size=17, radius=radius, device="cpu")
        cam = Camera(eye=(3 * radius, 0.2 * radius, 0.1 * radius), target=(0, 0, 0), up=(0, 0, 1), fov=0.3,
                     aspect=1.0, near=1e-3 * radius, far=10 * radius)
        for bounds in ("cone", "sphere"):
            m = g.mesh(error=1e-3 * radius, camera=cam, bounds=bounds)
            meshes.append((m.faces, m.vertices / radius))
    for (faces, vertices), (want_faces, want_vertices) in zip(meshes[2:], meshes[:2], strict=True):  # cone, sphere
        assert len(want_faces) < 12 * 16**2  # the clip test culls
        np.testing.assert_array_equal(faces, want_faces)
        np.testing.assert_allclose(vertices, want_vertices, rtol=0, atol=1e-6)


def test_the_gdalwarp_a_projected_texture_is_refused_with_leaves_the_poles_transparent_not_black(tmp_path):
    """A global texture in a projected CRS (a Web Mercator world map, to 85.05 degrees) is refused with the gdalwarp
    that puts it in degrees over the whole globe. Run as said, `gdalwarp -t_srs EPSG:4326 -te -180 -90 180 90`, the
    polar caps beyond the map were filled with opaque black and draped as black caps. It says -dstalpha now: the
    drape reads that alpha band, the caps are transparent, and all that is opaque is the map's colour."""
    import shlex
    import shutil
    import subprocess

    rasterio = pytest.importorskip("rasterio")
    from PIL import Image
    from rasterio.transform import Affine

    from stepterrain.globe import drape_colors

    from .conftest import shared_file

    if shutil.which("gdalwarp") is None:
        pytest.skip("gdalwarp (gdal-bin) is not installed")
    with Image.open(shared_file("earth_day_bluemarble_3840x1920.tif")) as picture:
        pixels = np.asarray(picture.convert("RGB"))[::16, ::16]  # 240 x 120, none of it black
    assert pixels.max(axis=2).min() > 0
    edge = 20037508.342789244  # the Web Mercator square, to 85.05 degrees
    with rasterio.open(tmp_path / "mercator.tif", "w", driver="GTiff", width=240, height=240, count=3, dtype="uint8",
                       crs="EPSG:3857", transform=Affine(2 * edge / 240, 0.0, -edge, 0.0, -2 * edge / 240, edge),
                       photometric="RGB") as out:
        out.write(np.moveaxis(np.asarray(Image.fromarray(pixels).resize((240, 240))), 2, 0))
    with pytest.raises(InvalidInputError, match="in a projected CRS: reproject it first") as refused:
        drape_colors(np.array([[EARTH_RADIUS, 0.0, 0.0]]), str(tmp_path / "mercator.tif"))
    command = re.search(r"\(`(gdalwarp[^`]*)`\)", str(refused.value)).group(1)
    words = [w for w in shlex.split(command) if w != "..."]
    subprocess.run([*words, "-q", "mercator.tif", "degrees.tif"], cwd=tmp_path, check=True, capture_output=True)
    lat, lon = np.meshgrid(np.radians(np.linspace(-89.5, 89.5, 180)), np.radians(np.linspace(-179.5, 179.5, 360)),
                           indexing="ij")
    directions = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    colors = drape_colors(directions.reshape(-1, 3) * EARTH_RADIUS, str(tmp_path / "degrees.tif")).reshape(180, 360, 4)
    caps = np.abs(np.degrees(lat)) > 86.0
    assert (colors[caps][:, 3] == 0).all(), "the polar caps beyond the map are opaque"
    assert (colors[np.abs(np.degrees(lat)) < 84.0][:, 3] == 255).all()
    opaque = colors[..., 3] == 255
    assert not (colors[opaque][:, :3] == 0).all(axis=1).any(), "opaque black where the map has no data"


@pytest.mark.parametrize("radius", [1.0, 6371000.0, 1e-20])
def test_an_eye_refused_just_under_the_surface_is_printed_apart_from_it(radius):
    """The refusal of an eye inside the planet printed |eye| and the surface to 0.1 m: on a globe of radius 1 (a unit
    sphere, heights scaled alike) an eye a millimetre under a peak read "|eye| = 1.0 m, the surface there 1.0 m from
    the centre (radius 1.0 m, terrain +0.0 m)", and on the earth an eye 1 cm under the surface read two equal
    numbers too. The numbers get the decimals that tell them apart (one where that suffices, as before); each is the
    value it names."""
    globe = Globe.from_latlon(np.full((18, 36), 0.01 * radius), np.linspace(85.0, -85.0, 18),
                              np.linspace(-175.0, 175.0, 36), face_size=9, radius=radius, device="cpu")
    surface = radius + globe._height_under(np.array([1.0, 0.0, 0.0]))
    eye = surface - 1e-5 * radius if radius != 6371000.0 else surface - 0.01
    with pytest.raises(InvalidInputError) as caught:
        globe.mesh(camera=Camera(eye=(eye, 0.0, 0.0), target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)))
    found = re.search(r"\|eye\| = (\S+) m, the surface there (\S+) m from the centre \(radius (\S+) m, terrain (\S+) "
                      r"m\)", str(caught.value))
    assert found, str(caught.value)
    printed_eye, printed_surface, printed_radius, printed_terrain = (float(v) for v in found.groups())
    assert printed_eye < printed_surface, str(caught.value)
    assert printed_eye == pytest.approx(eye, rel=1e-6) and printed_surface == pytest.approx(surface, rel=1e-6)
    assert printed_radius == pytest.approx(radius, rel=1e-6)
    assert printed_terrain == pytest.approx(surface - radius, rel=1e-3)


def test_a_planar_eye_refused_just_under_the_surface_is_printed_apart_from_it():
    """adaptive_mesh's refusal printed the surface and the eye to 0.1 m: a 1 mm model's eye 0.2 mm under it read
    "the surface is at z = 0.0 m, the eye at z = 0.0 m"."""
    z = np.full((5, 5), 0.001)
    eye = (0.002, 0.002, 0.0008)
    camera = Camera(eye=eye, target=(0.002, 0.002, 0.0), up=(0.0, 1.0, 0.0), near=1e-5, far=1.0)
    with pytest.raises(InvalidInputError) as caught:
        adaptive_mesh(z, error=1e-5, spacing=0.001, camera=camera, device="cpu")
    found = re.search(r"the surface is at z = (\S+) m, the eye at z = (\S+) m;", str(caught.value))
    assert found, str(caught.value)
    assert float(found.group(1)) == pytest.approx(0.001) and float(found.group(2)) == pytest.approx(0.0008)


@pytest.mark.parametrize("side, value", [("aux", "nan"), ("aux", "inf"), ("aux", "north nan"), ("tiff", "nan"),
                                          ("tiff", "inf"), ("tiff", "north nan")])
def test_a_texture_georeferenced_by_non_finite_numbers_is_refused_by_name(tmp_path, capsys, side, value):
    """A PAM file's GeoTransform or a GeoTIFF's tiepoint of NaN or inf (GDAL reads both as they are) crashed the drape
    with Python's ValueError / OverflowError (``round`` of the west edge: a traceback from ``stepterrain globe
    --texture``), and a NaN north edge passed every extent test (NaN compares false) and was draped as a global image
    from 180° W without a word. Refused now, naming the texture and where the numbers came from."""
    from PIL import Image, TiffImagePlugin

    from stepterrain.cli import main
    from stepterrain.globe import drape_colors, drape_texture

    west, north = ("nan" if value == "nan" else "inf" if value == "inf" else "-180"), \
        ("nan" if value == "north nan" else "90")
    pixels = np.zeros((4, 8, 3), np.uint8)
    if side == "aux":
        path = tmp_path / "earth.png"
        Image.fromarray(pixels).save(path)
        (tmp_path / "earth.png.aux.xml").write_text(f"<PAMDataset><GeoTransform>{west}, 45, 0, {north}, 0, -45"
                                                    "</GeoTransform></PAMDataset>")
        source = r"a PAM file 'earth\.png\.aux\.xml'"
    else:
        path = tmp_path / "earth.tif"
        info = TiffImagePlugin.ImageFileDirectory_v2()
        for tag, numbers in ((33550, (45.0, 45.0, 0.0)), (33922, (0.0, 0.0, 0.0, float(west), float(north), 0.0))):
            info[tag], info.tagtype[tag] = numbers, 12  # doubles
        info[34735], info.tagtype[34735] = (1, 1, 0, 2, 1024, 0, 1, 2, 1025, 0, 1, 1), 3  # geographic, PixelIsArea
        Image.fromarray(pixels).save(path, tiffinfo=info)
        source = "a GeoTIFF"
    directions = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) * EARTH_RADIUS
    message = rf"^texture .*earth\.\w+' must be georeferenced by finite numbers; got {source} with "
    with pytest.raises(InvalidInputError, match=message):
        drape_colors(directions, path)
    with pytest.raises(InvalidInputError, match=message):
        drape_texture(trimesh_sphere(), path)
    out = tmp_path / "g.glb"
    assert main(["-q", "globe", "--face-size", "5", "--no-camera", "--texture", str(path), "-o", str(out),
                 "--device", "cpu"]) == 2
    assert "must be georeferenced by finite numbers" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("radius", [2.0**-40, 2.0**-27, 2.0**40])  # about 1e-12, 7e-9, 1e12; powers of 2: exact
def test_a_globe_drape_is_the_same_at_any_radius(radius):
    """drape_texture took a vertex for a pole where it lay within 1e-9 (an absolute length, for |z| < 1) of the polar
    axis: on a globe of radius 1e-8 the ring of vertices round each pole became poles (their u the mean of their faces'
    other corners), at 1e-12 every vertex did (every u 0: the whole texture one column). Globe.from_latlon takes any
    radius from 1.18e-38; the drape depends on the directions alone: the same vertices, faces and UVs at any scale."""
    from stepterrain.globe import drape_texture

    mesh = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=65, radius=1.0, device="cpu").mesh()
    image = np.zeros((4, 8, 3), np.uint8)
    unit = drape_texture(mesh, image)
    scaled = mesh.copy()
    scaled.vertices = mesh.vertices * radius
    got = drape_texture(scaled, image)
    np.testing.assert_array_equal(got.faces, unit.faces)
    np.testing.assert_array_equal(got.visual.uv, unit.visual.uv)
    np.testing.assert_array_equal(got.vertices, unit.vertices * radius)


def _georeferenced_markers(tmp_path):
    """Global textures whose west edge is no whole number of pixels from 180° W, each with marker pixels (row, column,
    colour) and its geotransform (a, c, e, f: x = c + a·col, y = f + e·row at pixel corners), written without
    rasterio: an odd-width image over 0..360 (a world file: 180° W lies half-way across its column 22), and a
    node-registered 361 x 181 one (pixel centres on whole degrees, its edges at 180.5° W and 90.5° N: a PAM file, a
    PixelIsPoint GeoTIFF whose tiepoint is the first pixel's centre, and a JPEG with a world file)."""
    from PIL import Image, TiffImagePlugin

    rng = np.random.default_rng(7)
    cases = []
    odd = rng.integers(0, 60, (18, 45, 3)).astype(np.uint8)  # 8° columns from 0° E, 10° rows
    odd_markers = [(0, 0, (250, 10, 10)), (5, 22, (10, 250, 10)), (9, 44, (10, 10, 250)), (17, 30, (250, 250, 10)),
                   (12, 7, (250, 10, 250))]
    for i, j, colour in odd_markers:
        odd[i, j] = colour
    Image.fromarray(odd).save(tmp_path / "odd.png")
    (tmp_path / "odd.pgw").write_text("8\n0\n0\n-10\n4\n85\n")  # the upper-left pixel's centre: 4° E, 85° N
    cases.append((tmp_path / "odd.png", odd, odd_markers, (8.0, 0.0, -10.0, 90.0)))

    node = rng.integers(0, 60, (181, 361, 3)).astype(np.uint8)  # centres on whole degrees, 180° W to 180° E
    node[0] = (200, 200, 200)  # the north pole's row, the south pole's: one colour each
    node[180] = (90, 200, 250)
    node[:, 360] = node[:, 0]  # 180° W and 180° E: one meridian
    node_markers = [(40, 0, (250, 10, 10)), (40, 360, (250, 10, 10)), (90, 180, (10, 250, 10)),
                    (130, 359, (10, 10, 250)), (12, 1, (250, 250, 10)), (180, 77, (90, 200, 250)),
                    (67, 233, (250, 10, 250))]
    for i, j, colour in node_markers:
        node[i, j] = colour
    transform = (1.0, -180.5, -1.0, 90.5)
    Image.fromarray(node).save(tmp_path / "node.png")
    (tmp_path / "node.png.aux.xml").write_text("<PAMDataset><GeoTransform>-180.5, 1, 0, 90.5, 0, -1</GeoTransform>"
                                               "</PAMDataset>")
    cases.append((tmp_path / "node.png", node, node_markers, transform))
    info = TiffImagePlugin.ImageFileDirectory_v2()
    info[33550] = (1.0, 1.0, 0.0)
    info[33922] = (0.0, 0.0, 0.0, -180.0, 90.0, 0.0)  # PixelIsPoint: the first pixel's centre
    info[34735] = (1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 2, 2048, 0, 1, 4326)
    Image.fromarray(node).save(tmp_path / "node.tif", tiffinfo=info)
    cases.append((tmp_path / "node.tif", node, node_markers, transform))
    Image.fromarray(node).save(tmp_path / "node.jpg", quality=100)  # lossy: its UVs checked, not its colours
    (tmp_path / "node.jgw").write_text("1\n0\n0\n-1\n-180\n90\n")
    cases.append((tmp_path / "node.jpg", None, node_markers, transform))
    return cases


def _marker_directions(markers, transform):
    """Unit directions of the marker pixels' centres, from the geotransform alone (independent of the drape)."""
    a, c, e, f = transform
    lon = np.radians(np.array([c + a * (j + 0.5) for _, j, _ in markers]))
    lat = np.radians(np.array([f + e * (i + 0.5) for i, _, _ in markers]))
    return np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def test_a_texture_off_whole_columns_puts_each_pixel_centre_where_its_georeferencing_says(tmp_path):
    """A global texture whose west edge is no whole number of pixels from 180° W (an odd-width image over 0..360, a
    node-registered 361 x 181 one) was rolled by the nearest whole column and stretched over 360 x 180 degrees: each
    pixel landed up to half a pixel off (a node-registered one's, up to about a pixel, in rows too). drape_colors at a
    marker pixel's centre (its lat/lon from the geotransform) gave a blend of it and its neighbours. Now its colour is
    the marker's, exactly; drape_texture's UV of a vertex there is that pixel's centre in the embedded image."""
    import trimesh

    from stepterrain.globe import drape_colors, drape_texture

    for path, pixels, markers, transform in _georeferenced_markers(tmp_path):
        directions = _marker_directions(markers, transform)
        colours = np.array([colour for _, _, colour in markers])
        if pixels is not None:
            np.testing.assert_array_equal(drape_colors(directions * EARTH_RADIUS, path)[:, :3], colours,
                                          err_msg=str(path))
        # a small triangle at each marker: the marker, and points a tenth of a pixel west and south of it
        a, _, e, _ = transform
        lat, lon = np.arcsin(directions[:, 2]), np.arctan2(directions[:, 1], directions[:, 0])
        west = np.radians(a / 10)
        south = np.radians(-e / 10)
        lat_s = np.maximum(lat - south, -np.pi / 2)
        corners = [directions, np.column_stack([np.cos(lat) * np.cos(lon - west), np.cos(lat) * np.sin(lon - west),
                                                np.sin(lat)]),
                   np.column_stack([np.cos(lat_s) * np.cos(lon), np.cos(lat_s) * np.sin(lon), np.sin(lat_s)])]
        lat_n = np.minimum(lat + south, np.pi / 2)  # the south pole's marker: its triangle north of it
        corners[2][lat_s == -np.pi / 2] = np.column_stack([np.cos(lat_n) * np.cos(lon), np.cos(lat_n) * np.sin(lon),
                                                           np.sin(lat_n)])[lat_s == -np.pi / 2]
        n = len(markers)
        mesh = trimesh.Trimesh(np.concatenate(corners) * EARTH_RADIUS,
                               np.arange(3 * n).reshape(3, n).T, process=False)
        draped = drape_texture(mesh, path)
        image = np.asarray(draped.visual.material.image.convert("RGB"))
        height, width = image.shape[:2]
        uv = np.asarray(draped.visual.uv, dtype=np.float64)[:n]
        x, y = uv[:, 0] * width % width, (1 - uv[:, 1]) * height
        pole = np.abs(directions[:, 2]) == 1.0  # a pole's u is its face's (no pixel centre there)
        np.testing.assert_allclose(y - 0.5, np.round(y - 0.5), atol=1e-6, err_msg=str(path))
        np.testing.assert_allclose(x[~pole] - 0.5, np.round(x[~pole] - 0.5), atol=1e-6, err_msg=str(path))
        row, col = np.round(y - 0.5).astype(int), np.round(x - 0.5).astype(int) % width
        if pixels is not None:
            np.testing.assert_array_equal(image[row[~pole], col[~pole]], colours[~pole], err_msg=str(path))
            np.testing.assert_array_equal(image[row[pole], 0], colours[pole], err_msg=str(path))
        else:  # the JPEG's pixels without their closing column (column 360, 180° E, is column 0's meridian)
            assert width == 360
            expected = [(i, j % 360) for i, j, _ in markers]
            got = list(zip(row.tolist(), col.tolist(), strict=True))
            assert all(g == m for g, m, p in zip(got, expected, pole, strict=True) if not p), got
        # the seam: a globe's faces across the antimeridian span a few of the texture's columns, not the image (their
        # western corners' copies a turn on, u + 1); each face spans the columns of its longitudes, and at most the
        # one column more where the image's own ends meet (an odd-width image's blend of its ends)
        globe = Globe.from_latlon(np.zeros((180, 360)), LAT1, LON1, face_size=9, device="cpu").mesh(error=0.0)
        plain = drape_texture(globe, np.zeros((2, 2, 3), np.uint8))  # u = (lon + 180) / 360
        placed = drape_texture(globe, path)
        np.testing.assert_array_equal(placed.faces, plain.faces)
        turn = 360.0 / a  # the texture's columns in a turn
        spans = [np.ptp(np.asarray(m.visual.uv)[m.faces, 0], axis=1) for m in (plain, placed)]
        assert (spans[0] < 0.5).all() and (spans[1] * width <= spans[0] * turn + 1 + 1e-6).all(), str(path)


def test_the_cli_drapes_a_texture_off_whole_columns_where_its_georeferencing_says(tmp_path):
    """``stepterrain globe --texture`` decodes the texture once and drapes its pixels (vertex colours, and the UVs of
    a GLB): it passed them on as a bare array, plate carrée from 180° W, so a node-registered 361 x 181 image was
    stretched over 360 x 180 degrees (up to about a pixel off) even where drape_colors and drape_texture placed it.
    Now its georeferencing goes with them: the .ply's colours are drape_colors', and the .glb's UVs each vertex's
    pixel coordinate from the geotransform."""
    from stepterrain.cli import main
    from stepterrain.export import read_mesh
    from stepterrain.globe import drape_colors

    path = _georeferenced_markers(tmp_path)[1][0]  # node.png: its PAM file's -180.5, 1, 0, 90.5, 0, -1
    argv = ["-q", "globe", "--face-size", "17", "--error", "0", "--no-camera", "--device", "cpu", "--texture",
            str(path)]
    assert main([*argv, "-o", str(tmp_path / "earth.ply")]) == 0
    mesh = read_mesh(tmp_path / "earth.ply")
    np.testing.assert_allclose(np.asarray(mesh.visual.vertex_colors, dtype=float),
                               drape_colors(mesh.vertices, path).astype(float), atol=1)
    assert main([*argv, "-o", str(tmp_path / "earth.glb")]) == 0
    glb = read_mesh(tmp_path / "earth.glb")  # z up, as written
    vertices = np.asarray(glb.vertices, dtype=np.float64)
    lon = np.degrees(np.arctan2(vertices[:, 1], vertices[:, 0]))
    lat = np.degrees(np.arctan2(vertices[:, 2], np.hypot(vertices[:, 0], vertices[:, 1])))
    uv = np.asarray(glb.visual.uv, dtype=np.float64)
    pole = np.abs(lat) > 89.999
    x = (lon - -180.5) / 1.0  # pixel edges from the geotransform, not rolled (its west edge is 180.5 W)
    # modulo the image, its closing column (180° E, column 0's meridian again) dropped: 360 columns, u repeats
    off = (uv[:, 0] * 360 - x + 180) % 360 - 180
    assert glb.visual.material.baseColorTexture.size == (360, 181)
    assert (np.abs(off[~pole]) < 1e-3).all()
    np.testing.assert_allclose((1 - uv[:, 1]) * 181, 90.5 - lat, atol=1e-3)


def test_every_accepted_georeferencing_puts_each_pixel_centre_where_it_says(tmp_path):
    """Property: for global textures of random size whose georeferencing (a PAM file) starts anywhere round the
    globe, off whole columns, and spans up to 1.4 pixels more or less than 360 x 180 degrees (each accepted),
    drape_colors at each pixel's centre (its lat/lon from the geotransform) is that pixel's colour, and
    drape_texture's UV of a vertex there is that pixel's centre in the embedded image (its closing column dropped
    where one lies exactly a turn east of column 0: 2 pixels a turn over 3 columns), mapped back to that column. (A
    column whose centre the image's other end covers again, where it spans more than 360 degrees, and a row beyond a
    pole are skipped.) Pinned: the jump where a 5-column image overlaps itself by 1.375 columns lay at column 0's
    centre, which took the overlap's other copy (its longitude rounded a hair west); and a 3-column image of 2
    pixels a turn, whose UVs the test read against the file's width, not the embedded image's."""
    from hypothesis import example, given, settings
    from hypothesis import strategies as hst
    from PIL import Image

    from stepterrain.globe import drape_colors, drape_texture

    @settings(max_examples=25, deadline=None, derandomize=True)
    @given(hst.integers(3, 40), hst.integers(3, 20), hst.integers(0, 39), hst.floats(-0.5, 0.5),
           hst.floats(-1.4, 1.4), hst.floats(-1.4, 1.4), hst.floats(-1.4, 1.4))
    @example(3, 3, 0, 0.0, 1.0, 0.0, 0.0)  # a closing column: 2 columns embedded
    @example(5, 3, 1, 0.015625, 1.375, 0.0, 0.0)  # column 0's centre at the overlap's jump
    @example(17, 3, 1, 0.0, 1e-06, 0.0, 0.0)  # 1e-6 pixel from whole columns: read as plate carree from 180 W
    def check(width, height, start, offset, wide, tall, up):
        sx, sy = 360.0 / (width - wide), 180.0 / (height - tall)  # width - wide pixels in a turn
        west, north = -180.0 + ((start % width) + offset) * sx, 90.0 + up * sy
        rng = np.random.default_rng(width * 100 + height)
        pixels = rng.permutation(width * height * 3 * 4)[: width * height * 3].reshape(height, width, 3) % 256
        pixels = pixels.astype(np.uint8)
        path = tmp_path / "earth.png"
        Image.fromarray(pixels).save(path)
        (tmp_path / "earth.png.aux.xml").write_text(f"<PAMDataset><GeoTransform>{west!r}, {sx!r}, 0, {north!r}, 0, "
                                                    f"{-sy!r}</GeoTransform></PAMDataset>")
        row, col = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
        lat, lon = north - (row + 0.5) * sy, west + (col + 0.5) * sx
        keep = (np.abs(lat) < 90 - 1e-9) & (col < width - wide - 1e-6)  # off a pole, not the overlap's second copy
        lat, lon, row, col = np.radians(lat[keep]), np.radians(lon[keep]), row[keep], col[keep]
        directions = np.column_stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])
        got = drape_colors(directions * EARTH_RADIUS, path)[:, :3].astype(int)
        near = (got == pixels[row, col]).all(axis=1)
        assert near.all(), (west, north, sx, sy, row[~near], col[~near])
        n = len(directions)
        mesh = trimesh.Trimesh(directions, np.arange(n - n % 3).reshape(-1, 3), process=False)
        draped = drape_texture(mesh, path)
        image = np.asarray(draped.visual.material.image.convert("RGB"))
        embedded = image.shape[1]  # width - 1 where the last column repeats the first's meridian, else width
        assert image.shape[0] == height and embedded in ((width - 1,) if abs(wide - 1.0) < 1e-9 else
                                                         (width,) if abs(wide - 1.0) > 1e-6 else (width - 1, width))
        # the embedded image: the file's first `embedded` columns, rolled by some whole number of them
        rolls = [s for s in range(embedded) if (np.roll(pixels[:, :embedded], s, axis=1) == image).all()]
        assert rolls, "the embedded image is not the file's columns rolled"
        uv = np.asarray(draped.visual.uv, dtype=np.float64)[: n - n % 3]
        x, y = uv[:, 0] * embedded % embedded - 0.5, (1 - uv[:, 1]) * height - 0.5
        # within float32's resolution of the UVs (a placement within width·2^-24 pixels of whole columns is read as
        # plate carrée from 180 W, _Placement.whole_columns: a 17-column image 1e-6 pixel short of 17 a turn, its
        # last column 1.03e-6 pixel off)
        np.testing.assert_allclose(x, np.round(x), atol=embedded * 2.0**-22)
        np.testing.assert_allclose(y, np.round(y), atol=height * 2.0**-22)
        np.testing.assert_array_equal((np.round(x).astype(int) - rolls[0]) % embedded, col[: n - n % 3])
        np.testing.assert_array_equal(np.round(y).astype(int), row[: n - n % 3])
        texel = image[np.round(y).astype(int), np.round(x).astype(int) % embedded]
        np.testing.assert_array_equal(texel, pixels[row, col][: n - n % 3])

    import trimesh

    check()

def test_an_image_overlapping_itself_jumps_just_west_of_column_0s_centre(tmp_path):
    """A 5-column image of 3.625 columns a turn (it overlaps itself by 1.375 columns, west edge 1.015625 columns
    east of 180 W): column 0's centre, a hair either side, is column 0's colour (it took the other copy's blend, the
    overlap's jump lying at that centre, rounded a hair west); 0.3 pixel west of it the image's other end, between
    the neighbours in the image that lie either side there (columns 3 and 4: 3.325 columns from column 0's centre
    a turn on), as drape_texture's UVs."""
    from PIL import Image

    from stepterrain.globe import drape_colors, drape_texture

    width, period = 5, 3.625
    sx = 360.0 / period
    west = -180.0 + 1.015625 * sx
    pixels = (np.arange(width * 3 * 3).reshape(3, width, 3) * 17 % 251).astype(np.uint8)
    path = tmp_path / "earth.png"
    Image.fromarray(pixels).save(path)
    (tmp_path / "earth.png.aux.xml").write_text(f"<PAMDataset><GeoTransform>{west!r}, {sx!r}, 0, 90.0, 0, -60.0"
                                                "</GeoTransform></PAMDataset>")
    centre = west + 0.5 * sx
    lon = np.radians([centre - 1e-9, centre, centre + 1e-9, centre - 0.3 * sx])
    directions = np.column_stack([np.cos(lon), np.sin(lon), np.zeros(4)])  # the equator: row 1's centre
    got = drape_colors(directions * EARTH_RADIUS, path)[:, :3].astype(int)
    np.testing.assert_array_equal(got[:3], np.repeat(pixels[1, :1], 3, axis=0))
    blend = np.round(0.675 * pixels[1, 3].astype(float) + 0.325 * pixels[1, 4])
    np.testing.assert_array_equal(got[3], blend)
    import trimesh

    draped = drape_texture(trimesh.Trimesh(directions[:3], [[0, 1, 2]], process=False), path)
    x = np.asarray(draped.visual.uv, dtype=np.float64)[:, 0] * width % width - 0.5  # rolled by 1 column
    np.testing.assert_allclose(x, [1.0, 1.0, 1.0], atol=1e-5)


def test_drape_texture_checks_the_mesh_it_makes(monkeypatch):
    """drape_texture checked an image file's pixels but nothing of the mesh: its UVs, seam and pole copies and their
    working arrays took 137 bytes a face (a 786 432-face globe under a 90 x 180 texture: 103 MiB, unchecked). It now
    checks them before the work; its peak (numpy's allocations, traced) stays within what it counted, and a budget
    below that refuses it, naming the faces."""
    import tracemalloc

    import stepterrain as st
    import stepterrain.globe as globe_module
    from stepterrain.globe import Globe, drape_texture

    lat = np.linspace(89.5, -89.5, 180)
    lon = np.linspace(-179.5, 179.5, 360)
    mesh = Globe.from_latlon(np.zeros((180, 360)), lat, lon, face_size=65, device="cpu").mesh()
    image = np.zeros((90, 180, 3), np.uint8)
    counted = budget_counts(monkeypatch, globe_module)
    tracemalloc.start()
    try:
        out = drape_texture(mesh, image)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert counted and peak <= max(counted), f"drape_texture allocated {peak:,} bytes at its peak; counted {counted}"
    assert len(out.visual.uv) == len(out.vertices) > len(mesh.vertices)
    previous = st.set_memory_budget(peak // 2)
    try:
        with pytest.raises(st.OutputTooLargeError, match=r"draping a texture on a mesh of 49,152 faces"):
            drape_texture(mesh, image)
    finally:
        st.set_memory_budget(previous)


@pytest.mark.parametrize("bounds", ["cone", "sphere"])
def test_the_distance_metric_is_scale_free_up_to_the_ends_of_float64(bounds):
    """μ = e · (ℓ / d)² > ε depends on ℓ² / ε alone: ℓ = 1e200 with ε = 1e300 is ℓ = 1 with ε = 1e-100, and ℓ = 1e160
    with ε = 1 is ℓ = 1e10 with ε = 1e-300. Globe.mesh returned the 12 roots for the large pair (the spheres stood
    μ = 1e300 in for the eye inside a shape, no more than ε; the cones' μ · ℓ² overflowed, inf <= inf), 754 and 812
    triangles for the small one on the face-size-17 sample globe."""
    globe = Globe.sample(face_size=17, device="cpu")
    camera = look_from(10.0, 10.0, 1e6, max_radius=globe.radius + float(globe.heights.max()))

    def faces(error, scale):
        mesh = globe.mesh(error=error, camera=camera, bounds=bounds, distance_scale=scale, cull=False)
        return {tuple(sorted(t)) for t in np.asarray(mesh.metadata["node_entry"])[np.asarray(mesh.faces)].tolist()}

    small = faces(1e-100, 1.0)
    assert len(small) > 12
    assert faces(1e300, 1e200) == small
    assert faces(1.0, 1e160) == faces(1e-300, 1e10)

"""ParaView series: files read back with VTK's own readers match the state written."""
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem import paraview
from taichi_hsdem.paraview import FluidGrid, ParaViewUnavailable, SeriesWriter

try:
    import vtkmodules.vtkIOXML  # noqa: F401  (the readers the checks use)
    _vtk_missing = None
except ImportError as exc:
    _vtk_missing = exc
needs_vtk = pytest.mark.skipif(_vtk_missing is not None,
                               reason=f'VTK not importable ({_vtk_missing}): '
                                      f'pip install "taichi_hsdem[vtk]"')

# Two species: a 40-gon disk of radius 0.5 and an irregular (non-symmetric) quadrilateral,
# so that a wrong rotation direction or vertex order cannot pass.
_a = 2.0 * np.pi * np.arange(40) / 40
DISK = 0.5 * np.column_stack([np.cos(_a), np.sin(_a)])
QUAD = np.array([[-0.6, -0.2], [0.7, -0.3], [0.4, 0.5], [-0.3, 0.35]])
OUTLINE = np.array([[0.0, 0.0], [8.0, 0.0], [8.0, 3.0], [0.0, 3.0]])
OBSTACLE = np.array([[4.0, 1.0], [5.0, 1.5], [4.0, 2.0]])


def _state(shift):
    """Five particles, particle 3 not alive; positions and angles move with ``shift``."""
    x = np.array([[1.0, 1.0], [2.5, 1.2], [3.1, 2.2], [9.0, 9.0], [6.0, 0.8]]) + shift
    theta = np.array([0.0, 0.3, -1.2, 0.0, 2.9]) + shift
    v = np.array([[1.0, 0.0], [0.5, -0.25], [0.0, 2.0], [0.0, 0.0], [-1.5, 0.125]])
    omega = np.array([0.0, 1.5, -2.0, 0.0, 0.25])
    alive = np.array([True, True, True, False, True])
    species = np.array([0, 1, 1, 0, 0])
    return x, theta, v, omega, alive, species


def _outline_at(template, x, theta):
    """``template`` rotated by ``theta`` and moved to ``x``, as complex arithmetic."""
    z = (template[:, 0] + 1j * template[:, 1]) * np.exp(1j * theta) + (x[0] + 1j * x[1])
    return np.column_stack([z.real, z.imag])


def _read_polydata(path):
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader
    reader = vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    poly = reader.GetOutput()
    points = vtk_to_numpy(poly.GetPoints().GetData())
    cells = poly.GetPolys() if poly.GetNumberOfPolys() else poly.GetLines()
    offsets = vtk_to_numpy(cells.GetOffsetsArray())
    connectivity = vtk_to_numpy(cells.GetConnectivityArray())
    cell_points = [connectivity[a:b] for a, b in zip(offsets[:-1], offsets[1:])]
    data = poly.GetCellData()
    arrays = {data.GetArrayName(k): vtk_to_numpy(data.GetArray(k))
              for k in range(data.GetNumberOfArrays())}
    return poly, points, cell_points, arrays


def _read_image(path):
    from vtkmodules.vtkIOXML import vtkXMLImageDataReader
    reader = vtkXMLImageDataReader()
    reader.SetFileName(str(path))
    reader.Update()
    return reader.GetOutput()


def _collection(path):
    """{part name: [(timestep, file), ...]} of a .pvd."""
    out = {}
    for d in ET.parse(path).getroot().iter("DataSet"):
        out.setdefault(d.get("name"), []).append((float(d.get("timestep")), d.get("file")))
    return out


def _grid():
    active = np.ones((7, 3), dtype=bool)
    active[3, 0] = active[3, 2] = active[6, 1] = False
    return FluidGrid(origin=(-1.5, 0.25), spacing=(0.5, 0.25), active=active)


def _fields(grid, t):
    i, j = np.meshgrid(np.arange(grid.shape[0]), np.arange(grid.shape[1]), indexing="ij")
    p = np.where(grid.active, 100.0 * t + 10.0 * i + j, np.nan)
    k = np.where(grid.active, 1.0 + 0.5 * i - 0.25 * j, np.nan)
    return p, k


def _run(out, times=(0.0, 0.5), realizations=(0,), **kw):
    grid = _grid()
    with SeriesWriter(out, realizations, OUTLINE, [OBSTACLE], [DISK, QUAD], grid, **kw) as w:
        for t in times:
            p, k = _fields(grid, t)
            for r in realizations:
                w.write_frame(t, *_state(t + r), pressure=p, permeability=k, realization=r)
    return grid


@needs_vtk
def test_particle_outlines_at_final_positions(tmp_path):
    _run(tmp_path)
    poly, points, cells, data = _read_polydata(tmp_path / "vtk/r000/particles_000001.vtp")
    x, theta, v, omega, alive, species = _state(0.5)
    ids = np.flatnonzero(alive)                           # particle 3 is left out
    assert poly.GetNumberOfPolys() == len(ids) == 4
    np.testing.assert_array_equal(points[:, 2], 0.0)
    for cell, i in zip(cells, ids):
        expected = _outline_at([DISK, QUAD][species[i]], x[i], theta[i])
        np.testing.assert_allclose(points[cell, :2], expected, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(data["id"], ids)
    np.testing.assert_array_equal(data["species"], species[ids])
    np.testing.assert_array_equal(data["angle"], theta[ids])
    np.testing.assert_array_equal(data["omega"], omega[ids])
    np.testing.assert_array_equal(data["velocity"], np.column_stack([v[ids], np.zeros(4)]))


@needs_vtk
def test_fluid_grid_geometry_values_and_walls(tmp_path):
    grid = _run(tmp_path)
    image = _read_image(tmp_path / "vtk/r000/fluid_000001.vti")
    assert image.GetDimensions() == (8, 4, 1)             # points: cells + 1 along x, y
    assert image.GetNumberOfCells() == 21
    assert image.GetOrigin() == (-1.5, 0.25, 0.0)
    assert image.GetSpacing()[:2] == (0.5, 0.25)
    p_expected, k_expected = _fields(grid, 0.5)
    pressure = image.GetCellData().GetArray("pressure")
    permeability = image.GetCellData().GetArray("permeability")
    for cell in range(image.GetNumberOfCells()):
        # which grid cell this is, from the bounds VTK gives the cell
        b = [0.0] * 6
        image.GetCellBounds(cell, b)
        i, j = round((b[0] + b[1]) / 2 / 0.5 + 1.5 / 0.5 - 0.5), \
            round((b[2] + b[3]) / 2 / 0.25 - 0.25 / 0.25 - 0.5)
        assert (b[1] - b[0], b[3] - b[2], b[4], b[5]) == (0.5, 0.25, 0.0, 0.0)
        assert image.IsCellVisible(cell) == grid.active[i, j]
        if grid.active[i, j]:
            assert pressure.GetValue(cell) == p_expected[i, j]
            assert permeability.GetValue(cell) == k_expected[i, j]
        else:
            assert np.isnan(pressure.GetValue(cell)) and np.isnan(permeability.GetValue(cell))
    # the pressure range ParaView's colour map starts from skips the wall NaNs
    assert pressure.GetRange() == (50.0, 50.0 + 10.0 * 6 + 2)


@needs_vtk
def test_walls_are_closed_polylines(tmp_path):
    _run(tmp_path)
    _, points, lines, _ = _read_polydata(tmp_path / "vtk/walls.vtp")
    assert len(lines) == 2
    for line, polygon in zip(lines, (OUTLINE, OBSTACLE)):
        assert len(line) == len(polygon) + 1 and line[0] == line[-1]
        np.testing.assert_array_equal(points[line[:-1], :2], polygon)
        np.testing.assert_array_equal(points[line, 2], 0.0)


@needs_vtk
def test_collections_list_the_frames_with_their_times(tmp_path):
    _run(tmp_path, times=(0.0, 0.25, 0.75))
    local = _collection(tmp_path / "vtk/r000/series.pvd")
    top = _collection(tmp_path / "series.pvd")
    assert local["particles"] == [(0.0, "particles_000000.vtp"), (0.25, "particles_000001.vtp"),
                                  (0.75, "particles_000002.vtp")]
    assert local["fluid"] == [(0.0, "fluid_000000.vti"), (0.25, "fluid_000001.vti"),
                              (0.75, "fluid_000002.vti")]
    assert local["walls"] == [(t, "../walls.vtp") for t in (0.0, 0.25, 0.75)]
    for name, entries in local.items():
        # the top-level index points at the same files, from the output folder
        assert [((tmp_path / f).resolve(), t) for t, f in top[name]] == \
            [((tmp_path / "vtk/r000" / f).resolve(), t) for t, f in entries]
    parts = {d.get("name"): d.get("part")
             for d in ET.parse(tmp_path / "series.pvd").getroot().iter("DataSet")}
    assert parts == {"particles": "0", "walls": "1", "fluid": "2"}
    # nothing but the named files: no temporary left over
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*")
                     if p.is_file())
    assert written == ["series.pvd", "vtk/r000/fluid_000000.vti", "vtk/r000/fluid_000001.vti",
                       "vtk/r000/fluid_000002.vti", "vtk/r000/particles_000000.vtp",
                       "vtk/r000/particles_000001.vtp", "vtk/r000/particles_000002.vtp",
                       "vtk/r000/series.pvd", "vtk/walls.vtp"]


@needs_vtk
def test_several_realizations_top_level_is_the_first_given(tmp_path):
    _run(tmp_path, times=(0.0, 1.0), realizations=(2, 0))
    assert [f for _, f in _collection(tmp_path / "series.pvd")["particles"]] == \
        ["vtk/r002/particles_000000.vtp", "vtk/r002/particles_000001.vtp"]
    for r in (0, 2):
        _, points, cells, data = _read_polydata(tmp_path / f"vtk/r{r:03d}/particles_000001.vtp")
        x, theta, *_ = _state(1.0 + r)
        np.testing.assert_allclose(points[cells[0], :2], _outline_at(DISK, x[0], theta[0]),
                                   rtol=0, atol=1e-14)
    w = SeriesWriter(tmp_path / "b", [0, 1], OUTLINE, [], [DISK])
    with pytest.raises(ValueError, match="realization must be given"):
        w.write_frame(0.0, *_state(0.0)[:5], np.zeros(5, int))
    with pytest.raises(ValueError, match="realization 4 is not one of"):
        w.write_frame(0.0, *_state(0.0)[:5], np.zeros(5, int), realization=4)


@needs_vtk
def test_without_fluid_frames_have_particles_and_walls_only(tmp_path):
    with SeriesWriter(tmp_path, [0], OUTLINE, [], [DISK, QUAD]) as w:
        w.write_frame(0.0, *_state(0.0))
        with pytest.raises(ValueError, match="pressure given, but the writer has no grid"):
            w.write_frame(1.0, *_state(1.0), pressure=np.zeros((7, 3)))
    assert set(_collection(tmp_path / "series.pvd")) == {"particles", "walls"}


@needs_vtk
def test_interrupted_write_leaves_no_file_under_its_name(tmp_path, monkeypatch):
    w = SeriesWriter(tmp_path, [0], OUTLINE, [], [DISK, QUAD], _grid())
    w.write_frame(0.0, *_state(0.0))

    def interrupted(src, dst):
        raise KeyboardInterrupt

    monkeypatch.setattr(paraview.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        w.write_frame(1.0, *_state(1.0))
    monkeypatch.undo()
    assert not (tmp_path / "vtk/r000/particles_000001.vtp").exists()
    assert not list(tmp_path.rglob("*.part"))
    # the index written after frame 0 still stands and lists it alone
    assert _collection(tmp_path / "series.pvd")["particles"] == \
        [(0.0, "vtk/r000/particles_000000.vtp")]


@needs_vtk
def test_resume_keeps_earlier_frames_and_renumbers_later_ones(tmp_path):
    _run(tmp_path, times=(0.0, 1.0, 2.0, 3.0))
    grid = _grid()
    with SeriesWriter(tmp_path, [0], OUTLINE, [OBSTACLE], [DISK, QUAD], grid, resume=1.0) as w:
        w.write_frame(1.5, *_state(1.5), pressure=_fields(grid, 1.5)[0])
    top = _collection(tmp_path / "series.pvd")
    assert [t for t, _ in top["particles"]] == [0.0, 1.0, 1.5]
    assert [t for t, _ in top["fluid"]] == [0.0, 1.0, 1.5]
    assert not (tmp_path / "vtk/r000/particles_000003.vtp").exists()   # t = 3, dropped
    _, points, cells, _ = _read_polydata(tmp_path / "vtk/r000/particles_000002.vtp")
    x, theta, *_ = _state(1.5)
    np.testing.assert_allclose(points[cells[0], :2], _outline_at(DISK, x[0], theta[0]),
                               rtol=0, atol=1e-14)


@needs_vtk
@pytest.mark.parametrize("change, message", [
    (lambda s: s.update(t=0.0), "later than realization 0's previous frame"),
    (lambda s: s.update(species=np.array([0, 1, 2, 0, 0])), r"species must lie in \[0, 2\)"),
    (lambda s: s.update(x=np.zeros((4, 2))), r"x and v must be \(N, 2\)"),
    (lambda s: s.update(pressure=np.zeros((3, 7))), r"grid's shape \(7, 3\)"),
])
def test_invalid_frames_are_refused(tmp_path, change, message):
    w = SeriesWriter(tmp_path, [0], OUTLINE, [], [DISK, QUAD], _grid())
    w.write_frame(0.0, *_state(0.0))
    x, theta, v, omega, alive, species = _state(1.0)
    frame = dict(t=1.0, x=x, theta=theta, v=v, omega=omega, alive=alive, species=species)
    change(frame)
    with pytest.raises(ValueError, match=message):
        w.write_frame(**frame)


def test_missing_vtk_names_the_extra(tmp_path, monkeypatch):
    for name in [m for m in sys.modules if m.split(".")[0] == "vtkmodules"] + ["vtkmodules"]:
        monkeypatch.setitem(sys.modules, name, None)           # its import now fails
    paraview._vtk.cache_clear()
    try:
        with pytest.raises(ParaViewUnavailable, match=r'pip install "taichi_hsdem\[vtk\]"'):
            SeriesWriter(tmp_path, [0], OUTLINE, [], [DISK])
        assert not list(tmp_path.iterdir())                      # nothing written
    finally:
        paraview._vtk.cache_clear()


def test_the_series_holds_the_realizations_chosen(tmp_path, capsys):
    """``output.vtk_realizations``: by default the video's realization only, or the
    indices given; an index out of range is refused in one line (exit 2)."""
    from taichi_hsdem.cli import main
    scene = str(Path(__file__).resolve().parents[1] / "scenes" / "hourglass24.toml")
    base = [scene, "--realizations", "3", "--vtk", "--set", "run.t_end=0.2",
            "--set", "output.frames=3", "--quiet"]
    assert main(base + ["--out", str(tmp_path / "a")]) == 0
    assert sorted(p.name for p in (tmp_path / "a" / "vtk").glob("r*")) == ["r000"]
    assert main(base + ["--out", str(tmp_path / "b"),
                        "--set", 'output.vtk_realizations="2, 0"']) == 0
    assert sorted(p.name for p in (tmp_path / "b" / "vtk").glob("r*")) == ["r000", "r002"]
    capsys.readouterr()
    assert main(base + ["--out", str(tmp_path / "c"),
                        "--set", 'output.vtk_realizations="0,3"']) == 2
    err = capsys.readouterr().err
    assert "output.vtk_realizations" in err and "[0, 2]" in err and err.count("\n") == 1

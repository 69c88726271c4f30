"""ParaView output: a time series of the particles, the fluid grid and the walls.

A :class:`SeriesWriter` writes, for each frame of each realization it was given,

* the particles as VTK polydata (``.vtp``): one polygon cell per live particle,
  its template's outline rotated by the particle's angle and moved to its centre,
  with the cell data ``id``, ``species``, ``angle``, ``velocity`` and ``omega``;
* the fluid grid as VTK image data (``.vti``): one cell per pressure cell, with
  the cell data ``pressure`` and ``permeability``;

and once, the walls (the domain outline and the obstacles) as closed polylines.
A ParaView collection (``.pvd``) per realization lists every frame's files with
its time, so that ``paraview OUT/series.pvd`` opens the animation. Everything
lies in the plane ``z = 0``, in the units given (SI metres, or dimensionless).

Output layout, ``r`` the realization index::

    OUT/series.pvd                      the first realization's collection
    OUT/vtk/walls.vtp                   outline and obstacles, written once
    OUT/vtk/r000/series.pvd             realization 0's collection
    OUT/vtk/r000/particles_000000.vtp   frame 0, 1, ... of realization 0
    OUT/vtk/r000/fluid_000000.vti

Each collection time step holds up to three parts, which ParaView shows as the
blocks of one multiblock data set: ``particles`` (part 0), ``walls`` (part 1,
the same file at every step) and ``fluid`` (part 2, when the frame has one).

Choices
-------
* A particle that is not alive (escaped, or parked outside the domain) is left
  out of its frame, as in the video; the ``id`` cell array keeps the identities
  stable from frame to frame, so a particle's track survives the gaps.
* A wall cell of the fluid grid (``active`` false) keeps the values it is given
  (NaN from the pressure solver), which ParaView paints in the colour map's NaN
  colour, and is flagged hidden (``HIDDENCELL``) in the ``vtkGhostType`` cell
  array, VTK's blanking: VTK's filters that honour blanking leave it out.
* Data are written with VTK's own XML writers (``vtk`` on PyPI, imported only
  when a writer is made), binary, appended and LZ4-compressed. A missing ``vtk``
  raises :class:`ParaViewUnavailable` naming the pip extra.
* Every file is written under a temporary name in its final folder and renamed
  into place, and the collections are rewritten after every frame: an
  interrupted run leaves no half-written file under a final name, and the
  series written so far opens.

Examples
--------
>>> import numpy as np
>>> square = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
>>> box = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 5.0], [0.0, 5.0]])
>>> grid = FluidGrid(origin=(0.0, 0.0), spacing=1.0, active=np.ones((10, 5), bool))
>>> with SeriesWriter("run", [0], box, [], [square], grid) as out:  # doctest: +SKIP
...     out.write_frame(0.0, [[3.0, 2.0]], [0.5], [[1.0, 0.0]], [0.0], [True], [0],
...                     pressure=np.zeros((10, 5)), permeability=np.ones((10, 5)))
>>> # then: paraview run/series.pvd
"""
from __future__ import annotations

import os
import posixpath
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import SimpleNamespace

import numpy as np

INSTALL_HINT = 'pip install "taichi_hsdem[vtk]"'

# The collection's part numbers, fixed so that a series without fluid has no gap.
_PARTS = {"particles": 0, "walls": 1, "fluid": 2}


class ParaViewUnavailable(ImportError):
    """VTK's Python package, which writes the ParaView files, is not installed."""


@cache
def _vtk():
    """The VTK classes used here, imported on first use (about 0.3 s)."""
    try:
        from vtkmodules.util import numpy_support
        from vtkmodules.vtkCommonCore import vtkPoints
        from vtkmodules.vtkCommonDataModel import (vtkCellArray, vtkDataSetAttributes,
                                                   vtkImageData, vtkPolyData)
        from vtkmodules.vtkIOXML import vtkXMLImageDataWriter, vtkXMLPolyDataWriter
    except ImportError as exc:
        raise ParaViewUnavailable(
            f"ParaView output (--vtk, output.vtk) needs VTK's Python package: "
            f"{INSTALL_HINT} (import failed: {exc})") from exc
    return SimpleNamespace(np=numpy_support, Points=vtkPoints, CellArray=vtkCellArray,
                           Attributes=vtkDataSetAttributes, ImageData=vtkImageData,
                           PolyData=vtkPolyData, ImageWriter=vtkXMLImageDataWriter,
                           PolyWriter=vtkXMLPolyDataWriter)


@dataclass(frozen=True, eq=False)
class FluidGrid:
    """The fixed grid the pressure lives on.

    Parameters
    ----------
    origin : (x0, y0)
        Lower-left corner of cell ``(0, 0)``: cell ``(i, j)`` covers
        ``[x0 + i dx, x0 + (i+1) dx] x [y0 + j dy, y0 + (j+1) dy]``.
    spacing : float or (dx, dy)
        Cell size (one number for square cells).
    active : array_like of bool, shape (nx, ny)
        True for fluid cells, False for wall cells; x index first. Its shape is
        the grid's.

    Examples
    --------
    >>> g = FluidGrid(origin=(0.0, -1.0), spacing=0.5, active=np.ones((4, 2), bool))
    >>> g.shape, g.spacing
    ((4, 2), (0.5, 0.5))
    """

    origin: tuple
    spacing: tuple
    active: np.ndarray

    def __post_init__(self):
        origin = tuple(float(o) for o in np.ravel(self.origin))
        spacing = np.broadcast_to(np.asarray(self.spacing, dtype=float).ravel(), (2,))
        active = np.asarray(self.active)
        if len(origin) != 2 or not all(np.isfinite(origin)):
            raise ValueError(f"origin must be two finite numbers (x0, y0), got {self.origin!r}")
        if not (np.all(np.isfinite(spacing)) and np.all(spacing > 0)):
            raise ValueError(f"spacing must be positive: dx or (dx, dy), got {self.spacing!r}")
        if active.ndim != 2 or min(active.shape) < 1 or active.dtype != bool:
            raise ValueError(f"active must be a 2D boolean array (nx, ny), got dtype "
                             f"{active.dtype} and shape {active.shape}")
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "spacing", (float(spacing[0]), float(spacing[1])))
        object.__setattr__(self, "active", active.copy())

    @property
    def shape(self) -> tuple:
        """``(nx, ny)``, the number of cells along x and y."""
        return self.active.shape


def _as_polygon(poly, what):
    p = np.asarray(poly, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3 or not np.all(np.isfinite(p)):
        raise ValueError(f"{what} must be a finite (n >= 3, 2) array of vertices, "
                         f"got shape {p.shape}")
    return p


def _plane(xy):
    """(n, 2) -> (n, 3) with z = 0."""
    return np.column_stack([xy, np.zeros(len(xy))])


# VTK arrays below are deep copies: a shallow one would point into a numpy array
# that may be freed before the dataset is written.

def _id_array(values):
    return _vtk().np.numpy_to_vtkIdTypeArray(np.ascontiguousarray(values, dtype=np.int64),
                                             deep=True)


def _cells(offsets, connectivity):
    """A vtkCellArray from CSR offsets (ncells + 1, from 0) and point indices."""
    cells = _vtk().CellArray()
    cells.SetData(_id_array(offsets), _id_array(connectivity))
    return cells


def _add_cell_data(dataset, arrays):
    data = dataset.GetCellData()
    for name, values in arrays.items():
        array = _vtk().np.numpy_to_vtk(np.ascontiguousarray(values), deep=True)
        array.SetName(name)
        data.AddArray(array)


def _write(writer_class, dataset, path: Path):
    """``dataset`` to ``path`` through a temporary file in the same folder."""
    tmp = path.with_name(path.name + ".part")
    writer = writer_class()
    writer.SetFileName(str(tmp))
    writer.SetInputData(dataset)
    writer.SetDataModeToAppended()
    writer.EncodeAppendedDataOff()          # raw binary, not base64
    writer.SetHeaderTypeToUInt64()
    writer.SetCompressorTypeToLZ4()
    try:
        if writer.Write() != 1:
            raise OSError(f"VTK could not write {tmp} (disk full or not writable?)")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _write_collection(path: Path, entries):
    """A ParaView ``.pvd`` at ``path`` listing ``entries`` (t, part name, file)."""
    root = ET.Element("VTKFile", type="Collection", version="0.1",
                      byte_order="LittleEndian" if np.little_endian else "BigEndian")
    collection = ET.SubElement(root, "Collection")
    for t, name, file in entries:
        ET.SubElement(collection, "DataSet", timestep=repr(t), part=str(_PARTS[name]),
                      name=name, file=file)
    ET.indent(root)
    tmp = path.with_name(path.name + ".part")
    try:
        ET.ElementTree(root).write(tmp, encoding="utf-8", xml_declaration=True)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _read_collection(path: Path):
    """The entries (t, part name, file) of a ``.pvd`` this module wrote."""
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ValueError(f"cannot resume the ParaView series: {path} is unreadable "
                         f"({exc})") from exc
    return [(float(d.get("timestep")), d.get("name"), d.get("file"))
            for d in root.iter("DataSet")]


class SeriesWriter:
    """Writes the ParaView series of one or more realizations (module notes).

    Parameters
    ----------
    out_dir : str or Path
        The run's output folder; the files go to ``out_dir/vtk/`` and the index
        opened in ParaView is ``out_dir/series.pvd``.
    realizations : iterable of int
        The realizations to write, each to ``vtk/r<r:03d>/``. The first one is
        also indexed by ``out_dir/series.pvd``.
    outline : array_like, shape (M, 2)
        The fluid domain's boundary polygon.
    obstacles : list of array_like (k, 2)
        Solid islands inside the outline.
    templates : list of array_like (K_s, 2)
        Each species' outline in its body frame (centre at the origin, angle 0);
        a disk as a polygon of, e.g., 32 to 64 vertices.
    grid : FluidGrid, optional
        The pressure grid; without it frames carry no fluid.
    resume : float, optional
        Continue a series left in ``out_dir`` by a run resumed from time
        ``resume``: keep each realization's frames at times ``<= resume``, drop
        (and delete) the later ones, and number new frames after the kept ones.

    Raises
    ------
    ParaViewUnavailable
        VTK's Python package is not installed.
    ValueError
        A polygon, template, realization or the resumed series is invalid.

    Examples
    --------
    >>> disk = 0.5 * np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 48, endpoint=False)),
    ...                               np.sin(np.linspace(0, 2 * np.pi, 48, endpoint=False))])
    >>> box = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 2.0], [0.0, 2.0]])
    >>> writer = SeriesWriter("out", [0, 1], box, [], [disk])              # doctest: +SKIP
    >>> writer.write_frame(0.0, [[1.0, 1.0]], [0.0], [[0.0, 0.0]], [0.0], [True], [0],
    ...                    realization=1)                                   # doctest: +SKIP
    >>> writer.close()                                                      # doctest: +SKIP
    """

    def __init__(self, out_dir, realizations, outline, obstacles, templates, grid=None,
                 resume=None):
        _vtk()
        self.out_dir = Path(out_dir)
        self.realizations = [int(r) for r in realizations]
        if not self.realizations or min(self.realizations) < 0 \
                or len(set(self.realizations)) != len(self.realizations):
            raise ValueError(f"realizations must be distinct indices >= 0, at least one, "
                             f"got {self.realizations}")
        if grid is not None and not isinstance(grid, FluidGrid):
            raise ValueError(f"grid must be a FluidGrid or None, got {type(grid).__name__}")
        self.grid = grid
        shapes = [_as_polygon(s, f"template {k}") for k, s in enumerate(templates)]
        if not shapes:
            raise ValueError("templates must hold at least one particle outline")
        self._templates = shapes
        self._template_n = np.array([len(s) for s in shapes], dtype=np.int64)
        walls = [_as_polygon(outline, "outline")]
        walls += [_as_polygon(o, f"obstacle {k}") for k, o in enumerate(obstacles)]

        self.index = self.out_dir / "series.pvd"
        self.vtk_dir = self.out_dir / "vtk"
        self._dirs = {r: self.vtk_dir / f"r{r:03d}" for r in self.realizations}
        self._entries = {r: [] for r in self.realizations}   # (t, part name, file)
        self._frames = dict.fromkeys(self.realizations, 0)
        for d in self._dirs.values():
            d.mkdir(parents=True, exist_ok=True)
        if resume is not None:
            for r in self.realizations:
                self._resume(r, float(resume))
        self._write_walls(walls)
        self.closed = False

    def _resume(self, r, t_resume):
        path = self._dirs[r] / "series.pvd"
        if not path.exists():
            return
        kept = []
        for t, name, file in _read_collection(path):
            if t <= t_resume:
                kept.append((t, name, file))
            elif name != "walls":
                (self._dirs[r] / file).unlink(missing_ok=True)
        self._entries[r] = kept
        self._frames[r] = sum(name == "particles" for _, name, _ in kept)

    def _write_walls(self, polygons):
        vtk = _vtk()
        sizes = np.array([len(p) for p in polygons])
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        # a closed polyline repeats its first point at the end
        connectivity = np.concatenate([np.append(np.arange(n) + s, s)
                                       for s, n in zip(starts, sizes)])
        walls = vtk.PolyData()
        points = vtk.Points()
        points.SetData(vtk.np.numpy_to_vtk(_plane(np.vstack(polygons)), deep=True))
        walls.SetPoints(points)
        walls.SetLines(_cells(np.concatenate([[0], np.cumsum(sizes + 1)]), connectivity))
        _write(vtk.PolyWriter, walls, self.vtk_dir / "walls.vtp")

    def write_frame(self, t, x, theta, v, omega, alive, species, pressure=None,
                    permeability=None, *, realization=None):
        """Write one realization's state at time ``t`` and update its index.

        Parameters
        ----------
        t : float
            Time, later than the realization's previous frame.
        x : array_like (N, 2)
            Particle centres.
        theta : array_like (N,)
            Angles, rad, counter-clockwise.
        v : array_like (N, 2)
            Velocities (written with z = 0, so that ParaView glyphs can use them).
        omega : array_like (N,)
            Angular velocities, rad per time unit.
        alive : array_like (N,) of bool
            Particles written; the others are left out (module notes).
        species : array_like (N,) of int
            Template index of each particle.
        pressure, permeability : array_like (nx, ny), optional
            Cell values on the writer's grid, x index first (NaN in walls). The
            frame gets a ``.vti`` when either is given.
        realization : int, optional
            Which realization this is; may be left out when the writer has one.

        Raises
        ------
        ValueError
            An array has the wrong shape, a species is out of range, ``t`` does
            not follow the previous frame, a field is given without a grid, or
            the realization is not one of the writer's.
        RuntimeError
            The writer is closed.

        Examples
        --------
        >>> writer.write_frame(0.1, x, theta, v, omega, alive, species,
        ...                    pressure=p, realization=0)                 # doctest: +SKIP
        """
        if self.closed:
            raise RuntimeError("write_frame on a closed SeriesWriter")
        r = self._realization(realization)
        t = float(t)
        entries = self._entries[r]
        if not np.isfinite(t) or (entries and t <= entries[-1][0]):
            last = entries[-1][0] if entries else None
            raise ValueError(f"frame time {t!r} must be finite and later than realization "
                             f"{r}'s previous frame (t = {last!r})")
        particles = self._particles(x, theta, v, omega, alive, species)
        fluid = self._fluid(pressure, permeability)

        k = self._frames[r]
        name = f"particles_{k:06d}.vtp"
        _write(_vtk().PolyWriter, particles, self._dirs[r] / name)
        entries.append((t, "particles", name))
        entries.append((t, "walls", "../walls.vtp"))
        if fluid is not None:
            name = f"fluid_{k:06d}.vti"
            _write(_vtk().ImageWriter, fluid, self._dirs[r] / name)
            entries.append((t, "fluid", name))
        self._frames[r] = k + 1
        self._write_index(r)

    @property
    def frames_written(self) -> int:
        """Frames in the series, over all realizations (kept ones of a resumed
        series included)."""
        return sum(self._frames.values())

    def last_time(self, realization=None) -> float | None:
        """Time of the realization's latest frame, or None before the first."""
        entries = self._entries[self._realization(realization)]
        return entries[-1][0] if entries else None

    def _realization(self, realization):
        if realization is None:
            if len(self.realizations) != 1:
                raise ValueError(f"realization must be given: this writer writes "
                                 f"{self.realizations}")
            return self.realizations[0]
        if int(realization) not in self._dirs:
            raise ValueError(f"realization {realization} is not one of this writer's "
                             f"{self.realizations}")
        return int(realization)

    def _particles(self, x, theta, v, omega, alive, species):
        """The live particles' outlines in world coordinates, as vtkPolyData."""
        x = np.asarray(x, dtype=np.float64)
        n = len(x)
        theta, omega = (np.asarray(a, dtype=np.float64).reshape(-1) for a in (theta, omega))
        v = np.asarray(v, dtype=np.float64)
        alive = np.asarray(alive, dtype=bool).reshape(-1)
        species = np.asarray(species).reshape(-1)
        if x.shape != (n, 2) or v.shape != (n, 2) or not (
                len(theta) == len(omega) == len(alive) == len(species) == n):
            raise ValueError(f"x and v must be (N, 2), theta, omega, alive and species (N,); "
                             f"got {x.shape}, {v.shape}, {theta.shape}, {omega.shape}, "
                             f"{alive.shape}, {species.shape}")
        if n and not np.issubdtype(species.dtype, np.integer):
            raise ValueError(f"species must be integers, got dtype {species.dtype}")
        if n and (species.min() < 0 or species.max() >= len(self._template_n)):
            raise ValueError(f"species must lie in [0, {len(self._template_n)}) (one per "
                             f"template), got {species.min()}..{species.max()}")
        ids = np.flatnonzero(alive)
        sp = species[ids].astype(np.int64)
        offsets = np.concatenate([[0], np.cumsum(self._template_n[sp])])
        # cell k is the k-th live particle; its points are its template's vertices
        world = np.zeros((offsets[-1], 3))
        for s, template in enumerate(self._templates):
            mine = np.flatnonzero(sp == s)
            rows = (offsets[mine][:, None] + np.arange(len(template))).ravel()
            c, sn = (f(theta[ids[mine]])[:, None] for f in (np.cos, np.sin))
            centre = x[ids[mine]]
            world[rows, 0] = (centre[:, :1] + c * template[:, 0] - sn * template[:, 1]).ravel()
            world[rows, 1] = (centre[:, 1:] + sn * template[:, 0] + c * template[:, 1]).ravel()
        vtk = _vtk()
        poly = vtk.PolyData()
        points = vtk.Points()
        points.SetData(vtk.np.numpy_to_vtk(world, deep=True))
        poly.SetPoints(points)
        poly.SetPolys(_cells(offsets, np.arange(offsets[-1])))
        _add_cell_data(poly, {"id": ids.astype(np.int64), "species": sp,
                              "angle": theta[ids], "velocity": _plane(v[ids]),
                              "omega": omega[ids]})
        return poly

    def _fluid(self, pressure, permeability):
        """The grid with its fields as vtkImageData, or None without fields."""
        fields = {name: f for name, f in (("pressure", pressure),
                                          ("permeability", permeability)) if f is not None}
        if not fields:
            return None
        if self.grid is None:
            raise ValueError(f"{' and '.join(fields)} given, but the writer has no grid")
        g = self.grid
        vtk = _vtk()
        image = vtk.ImageData()
        image.SetOrigin(*g.origin, 0.0)
        image.SetSpacing(*g.spacing, 1.0)      # one layer of points: z spacing unused
        image.SetDimensions(g.shape[0] + 1, g.shape[1] + 1, 1)
        arrays = {}
        for name, f in fields.items():
            f = np.asarray(f, dtype=np.float64)
            if f.shape != g.shape:
                raise ValueError(f"{name} must have the grid's shape {g.shape} (x first), "
                                 f"got {f.shape}")
            arrays[name] = f.ravel(order="F")            # VTK's cell order: x fastest
        hidden = np.where(g.active, 0, vtk.Attributes.HIDDENCELL).astype(np.uint8)
        arrays[vtk.Attributes.GhostArrayName()] = hidden.ravel(order="F")
        _add_cell_data(image, arrays)
        return image

    def _write_index(self, r):
        _write_collection(self._dirs[r] / "series.pvd", self._entries[r])
        if r == self.realizations[0]:
            prefix = self._dirs[r].relative_to(self.out_dir).as_posix()
            _write_collection(self.index, [(t, name, posixpath.normpath(f"{prefix}/{file}"))
                                           for t, name, file in self._entries[r]])

    def close(self):
        """Write every realization's index (also those that got no frame)."""
        if not self.closed:
            for r in self.realizations:
                self._write_index(r)
            self.closed = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

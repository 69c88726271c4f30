"""Level-set grids of the shape templates: a template's exact signed distance
(:func:`~taichi_hsdem.geometry.distance.signed_distance`) sampled on a regular grid
in its body frame, read back by bilinear interpolation as the contact kernels do,
and :func:`stack`, which lays every template out in flat arrays for upload to
Taichi (one grid and one node list per template, with offsets)."""
from __future__ import annotations

import operator
from dataclasses import dataclass

import numpy as np

from .distance import signed_distance
from .shapes import check_positive, concat_arrays, frozen

__all__ = ["OUTSIDE_PHI", "LevelSetGrid", "make_level_set", "sample", "stack"]


#: Level-set value returned for points outside a grid: far enough that no
#: contact test (``phi < 0``) can fire, finite so it survives float32 upload.
OUTSIDE_PHI = 1.0e30


@dataclass(frozen=True, eq=False)
class LevelSetGrid:
    """Signed distance of one template sampled on a regular grid (body frame).

    Attributes
    ----------
    origin : ndarray of shape (2,)
        Body-frame coordinates of grid node ``(0, 0)``.
    spacing : float
        Distance between neighbouring grid nodes, the same along x and y.
    phi : ndarray of shape (nx, ny)
        ``phi[i, j]`` is the signed distance at ``origin + (i, j) * spacing``
        (x-first indexing).
    """

    origin: np.ndarray
    spacing: float
    phi: np.ndarray


def make_level_set(shape, spacing, margin_cells=3) -> LevelSetGrid:
    """Sample a shape's exact signed distance on a regular grid.

    The grid covers the shape's bounding box, centred on it, plus
    ``margin_cells`` cells on every side, so that nodes of a neighbour slightly
    outside the shape still read a meaningful (positive) distance.

    Parameters
    ----------
    shape : Shape
    spacing : float
        Grid spacing, > 0 (the scene's ``ls_spacing``).
    margin_cells : int, optional
        Cells added beyond the bounding box on each side, >= 1.

    Returns
    -------
    LevelSetGrid

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import square
    >>> g = make_level_set(square(1.0), 0.25, margin_cells=1)
    >>> g.phi.shape, g.origin.tolist()
    ((7, 7), [-0.75, -0.75])
    """
    h = check_positive("spacing", spacing)
    try:
        margin = operator.index(margin_cells)
    except TypeError:
        raise ValueError(f"margin_cells must be an integer, got {margin_cells!r}") from None
    if margin < 1:
        raise ValueError(f"margin_cells must be >= 1, got {margin}")
    if shape.kind == "circle":
        lo = np.full(2, -shape.radius)
        hi = np.full(2, shape.radius)
    else:
        lo = shape.vertices.min(axis=0)
        hi = shape.vertices.max(axis=0)
    # The small allowance keeps a box that is a whole number of cells wide from
    # gaining a cell to round-off; the slack of a partial cell is split evenly
    # so symmetric shapes get symmetric grids.
    cells = np.ceil((hi - lo) / h - 1e-9).astype(int)
    origin = lo - 0.5 * (cells * h - (hi - lo)) - margin * h
    nx, ny = cells + 2 * margin + 1
    gx = origin[0] + h * np.arange(nx)
    gy = origin[1] + h * np.arange(ny)
    pts = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1)
    phi = signed_distance(shape, pts)
    return LevelSetGrid(origin=frozen(origin), spacing=h, phi=frozen(phi))


def sample(grid, points) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear level-set value and its gradient at body-frame points.

    The gradient is that of the bilinear interpolant itself (what the contact
    kernels normalise into a contact normal), not a finite-difference stencil.

    Parameters
    ----------
    grid : LevelSetGrid
    points : array_like of shape (..., 2)
        Body-frame points.

    Returns
    -------
    phi : ndarray of shape (...)
        Interpolated signed distance; `OUTSIDE_PHI` for points outside the grid.
    grad : ndarray of shape (..., 2)
        Gradient of the interpolant; zero outside the grid.

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import square
    >>> g = make_level_set(square(1.0), 0.05)
    >>> phi, grad = sample(g, [[0.6, 0.0], [9.0, 9.0]])
    >>> phi.round(12).tolist(), grad.round(12).tolist()
    ([0.1, 1e+30], [[1.0, 0.0], [0.0, 0.0]])
    """
    p = np.asarray(points, dtype=float)
    if p.shape[-1:] != (2,):
        raise ValueError(f"points must have shape (..., 2), got {p.shape}")
    nx, ny = grid.phi.shape
    u = (p[..., 0] - grid.origin[0]) / grid.spacing
    w = (p[..., 1] - grid.origin[1]) / grid.spacing
    # Written so that NaN coordinates also land outside.
    inside = (u >= 0) & (u <= nx - 1) & (w >= 0) & (w <= ny - 1)
    u = np.where(inside, u, 0.0)
    w = np.where(inside, w, 0.0)
    # A point on the last grid line belongs to the last cell, at t = 1.
    i = np.minimum(np.floor(u).astype(int), nx - 2)
    j = np.minimum(np.floor(w).astype(int), ny - 2)
    tx = u - i
    ty = w - j
    f = grid.phi
    f00, f10, f01, f11 = f[i, j], f[i + 1, j], f[i, j + 1], f[i + 1, j + 1]
    phi = (1 - tx) * (1 - ty) * f00 + tx * (1 - ty) * f10 + (1 - tx) * ty * f01 + tx * ty * f11
    gx = ((1 - ty) * (f10 - f00) + ty * (f11 - f01)) / grid.spacing
    gy = ((1 - tx) * (f01 - f00) + tx * (f11 - f10)) / grid.spacing
    phi = np.where(inside, phi, OUTSIDE_PHI)
    grad = np.where(inside[..., None], np.stack([gx, gy], axis=-1), 0.0)
    return phi, grad


def stack(shapes, spacings) -> dict:
    """Lay all templates' level sets and surface nodes out in flat arrays.

    This is the layout the Taichi fields take: one flat level-set array with a
    per-template offset, shape, origin and spacing, and the surface nodes of all
    templates one after another (nodes are stored once per template and moved
    with each particle on the fly).

    Parameters
    ----------
    shapes : sequence of Shape
        The templates; template ``k`` is ``shapes[k]``.
    spacings : sequence of float or None
        Level-set spacing of each template. ``None`` is allowed for a circle and
        builds no grid for it: disks use the analytic contact.

    Returns
    -------
    dict of ndarray
        With ``T = len(shapes)``:

        * ``ls_phi`` (sum nx*ny,) float64: grid ``k`` flattened x-first, value
          ``(i, j)`` at ``ls_offset[k] + i * ny + j``;
        * ``ls_offset`` (T,) int32; ``ls_shape`` (T, 2) int32, ``(nx, ny)``,
          ``(0, 0)`` where no grid was built;
        * ``ls_origin`` (T, 2), ``ls_spacing`` (T,) float64 (0 where no grid);
        * ``node_pos`` (N, 2), ``node_len`` (N,), ``node_normal`` (N, 2) float64;
        * ``node_offset``, ``node_count`` (T,) int32;
        * ``is_circle`` (T,) int32; ``radius``, ``bounding_radius`` (T,) float64.

    Examples
    --------
    >>> from taichi_hsdem.geometry.shapes import circle, square
    >>> d = stack([circle(1.0), square(1.0)], [None, 0.1])
    >>> d["ls_shape"].tolist(), d["ls_offset"].tolist(), d["node_offset"].tolist()
    ([[0, 0], [17, 17]], [0, 0], [0, 40])
    """
    shapes = list(shapes)
    spacings = list(spacings)
    if len(shapes) != len(spacings):
        raise ValueError(f"got {len(shapes)} shapes but {len(spacings)} spacings")
    t = len(shapes)
    ls_offset = np.zeros(t, dtype=np.int32)
    ls_shape = np.zeros((t, 2), dtype=np.int32)
    ls_origin = np.zeros((t, 2))
    ls_spacing = np.zeros(t)
    phis = []
    total = 0
    for k, (shape, h) in enumerate(zip(shapes, spacings)):
        ls_offset[k] = total
        if h is None:
            if shape.kind != "circle":
                raise ValueError(
                    f"template {k} ({shape.name}) is a polygon and needs a level-set spacing, got None"
                )
            continue
        grid = make_level_set(shape, h)
        ls_shape[k] = grid.phi.shape
        ls_origin[k] = grid.origin
        ls_spacing[k] = grid.spacing
        phis.append(grid.phi.ravel())  # C order: index i * ny + j
        total += grid.phi.size
    counts = np.array([len(s.nodes) for s in shapes], dtype=np.int32)
    return {
        "ls_phi": np.concatenate(phis) if phis else np.zeros(0),
        "ls_offset": ls_offset,
        "ls_shape": ls_shape,
        "ls_origin": ls_origin,
        "ls_spacing": ls_spacing,
        "node_pos": concat_arrays([s.nodes for s in shapes], (0, 2)),
        "node_len": concat_arrays([s.node_lengths for s in shapes], (0,)),
        "node_normal": concat_arrays([s.node_normals for s in shapes], (0, 2)),
        "node_offset": (np.cumsum(counts) - counts).astype(np.int32),
        "node_count": counts,
        "is_circle": np.array([s.kind == "circle" for s in shapes], dtype=np.int32),
        "radius": np.array([s.radius for s in shapes], dtype=float),
        "bounding_radius": np.array([s.bounding_radius for s in shapes], dtype=float),
    }

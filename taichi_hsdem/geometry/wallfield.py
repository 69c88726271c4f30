"""The wall level set on a regular grid: the exact signed distance to the walls
(:func:`taichi_hsdem.geometry.walls.wall_distance`) sampled once per scene, and its
bilinear interpolation, which the contact kernels read (docs/model.md section 1).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .walls import _REL_TOL, Geometry, _require, wall_distance


@dataclass(frozen=True, eq=False)
class WallField:
    """The wall level set sampled on a regular grid, x-first.

    Attributes
    ----------
    origin : (2,) ndarray
        Position of node ``(0, 0)``, m.
    spacing : float
        Grid spacing ``h``, m.
    phi : (nx, ny) ndarray
        ``phi[i, j] = wall_distance(geometry, origin + (i, j) * spacing)``.
    """
    origin: np.ndarray
    spacing: float
    phi: np.ndarray


def make_wall_field(geometry: Geometry, spacing: float, margin: float | None = None) -> WallField:
    """Sample `wall_distance` on a grid covering the bounding box plus a margin.

    Parameters
    ----------
    geometry : Geometry
    spacing : float
        Grid spacing, m (the scene's ``geometry.wall_cell_size``).
    margin : float, optional
        Extra width on every side, m; default ``4 * spacing``, so that a node that
        has sunk a few cells into a wall still reads a distance, not a clamp.

    Returns
    -------
    WallField

    Examples
    --------
    >>> from taichi_hsdem.geometry.walls import hourglass
    >>> f = make_wall_field(hourglass(10.0, 2.0, 0.5), spacing=0.1)
    >>> f.phi.shape, f.origin.tolist()
    ((109, 29), [-0.4, -1.4])
    """
    h = float(spacing)
    _require(h > 0, f"wall field spacing must be > 0, got {h}")
    m = 4 * h if margin is None else float(margin)
    _require(m >= 0, f"wall field margin must be >= 0, got {m}")
    origin = np.array([geometry.x_min - m, geometry.y_min - m])
    # ceil with a relative slack: a box that is an exact multiple of h must not
    # gain a node from the rounding error of the division.
    n = [int(np.ceil((span + 2 * m) / h - _REL_TOL)) + 1
         for span in (geometry.x_max - geometry.x_min, geometry.y_max - geometry.y_min)]
    gx = origin[0] + h * np.arange(n[0])
    gy = origin[1] + h * np.arange(n[1])
    pts = np.stack(np.meshgrid(gx, gy, indexing="ij"), axis=-1).reshape(-1, 2)
    phi = wall_distance(geometry, pts).reshape(n[0], n[1])
    origin.setflags(write=False)
    phi.setflags(write=False)
    return WallField(origin=origin, spacing=h, phi=phi)


def sample_wall(field: WallField, points):
    """Bilinear interpolation of a `WallField` and the exact gradient of the interpolant.

    Points outside the grid are extrapolated linearly from the nearest cell.

    Parameters
    ----------
    field : WallField
    points : (M, 2) array_like

    Returns
    -------
    phi : (M,) ndarray
    grad : (M, 2) ndarray

    Examples
    --------
    >>> from taichi_hsdem.geometry.walls import hourglass
    >>> f = make_wall_field(hourglass(10.0, 2.0, 0.5), spacing=0.1)
    >>> phi, grad = sample_wall(f, [[1.0, 0.7]])
    >>> round(float(phi[0]), 12), [round(float(g), 12) for g in grad[0]]
    (0.3, [0.0, -1.0])
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    h = field.spacing
    nx, ny = field.phi.shape
    f = (pts - field.origin) / h
    i = np.clip(np.floor(f[:, 0]).astype(np.int64), 0, nx - 2)
    j = np.clip(np.floor(f[:, 1]).astype(np.int64), 0, ny - 2)
    tx, ty = f[:, 0] - i, f[:, 1] - j
    p00, p10 = field.phi[i, j], field.phi[i + 1, j]
    p01, p11 = field.phi[i, j + 1], field.phi[i + 1, j + 1]
    phi = (1 - tx) * (1 - ty) * p00 + tx * (1 - ty) * p10 + (1 - tx) * ty * p01 + tx * ty * p11
    gx = ((1 - ty) * (p10 - p00) + ty * (p11 - p01)) / h
    gy = ((1 - tx) * (p01 - p00) + tx * (p11 - p10)) / h
    return phi, np.stack([gx, gy], axis=1)

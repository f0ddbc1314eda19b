"""The bilateral grid's sampling: cell sizes, shape and blur of a guide's grid.

Free of numba: the decoders' memory estimate (:mod:`stereobudget.decoding`) sizes the grids
with the same function the fill allocates them with, before any kernel loads.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class GridGeometry:
    """Sampling of the bilateral grid.

    Attributes
    ----------
    cell_s : float
        Spatial cell size in pixels.
    cell_r : float
        Range cell size in guide intensity units.
    shape : tuple of int
        (GY, GX, GZ) grid cells.
    blur_s, blur_r : float
        Standard deviations of the grid blur, in cells.
    """

    cell_s: float
    cell_r: float
    shape: tuple
    blur_s: float
    blur_r: float


def grid_geometry(height: int, width: int, guide_max: float, *, sigma_s: float, sigma_r: float,
                  cells_per_sigma_s: float = 2.0, cells_per_sigma_r: float = 2.0) -> GridGeometry:
    """Choose grid cells so each sigma spans ``cells_per_sigma`` cells (2 keeps errors near 1 %)."""
    cell_s = max(sigma_s / cells_per_sigma_s, 1.0)
    cell_r = max(sigma_r / cells_per_sigma_r, 1e-3)
    # Hat-function splat + slice add 2 * (1/6) cell^2 of variance per axis.
    blur_s = math.sqrt(max((sigma_s / cell_s) ** 2 - 1.0 / 3.0, 1e-6))
    blur_r = math.sqrt(max((sigma_r / cell_r) ** 2 - 1.0 / 3.0, 1e-6))
    gy = int(math.floor((height - 1) / cell_s)) + 2
    gx = int(math.floor((width - 1) / cell_s)) + 2
    gz = int(math.floor(max(guide_max, 0.0) / cell_r)) + 2
    return GridGeometry(cell_s, cell_r, (gy, gx, gz), blur_s, blur_r)


__all__ = ["GridGeometry", "grid_geometry"]

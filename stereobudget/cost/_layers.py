"""How many layers a cost volume holds per pixel: the layout every volume, kernel and memory
estimate shares (free of numba)."""

from __future__ import annotations

#: Volume rows are padded to a multiple of this many float32 layers (32 bytes).
LAYER_QUANTUM = 8


def volume_layers(num_disp: int) -> int:
    """Layers a decoder computes and stores per pixel for ``num_disp`` disparities.

    ``num_disp`` rounded up to a multiple of :data:`LAYER_QUANTUM`: the extra layers
    are the next disparities, computed and aggregated like the others (every layer is
    independent of the rest) but never allowed to win.  Rows of whole 32-byte vectors
    leave no scalar tail in any per-pixel loop and keep the rows of 64 layers on cache
    lines: Teddy's 61 disparities decode faster as 64 layers than as 61 (the cost kernel
    ~14 %, scripts/bench.py).
    """
    num_disp = int(num_disp)
    return -(-num_disp // LAYER_QUANTUM) * LAYER_QUANTUM


__all__ = ["LAYER_QUANTUM", "volume_layers"]

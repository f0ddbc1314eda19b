"""Filling the sparse DSI (Eq. 2) by the normalised joint bilateral filter (Eq. 3, 4) on a bilateral grid, and the low-pass fills Hybrid mixes in."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_geometry': ['GridGeometry', 'grid_geometry'],
    '_grid': ['SliceGrids', 'slice_scratch', 'slice_pixel', 'slice_volume', 'sparse_joint_bilateral', 'release_grids'],
    '_bilateral': ['FillScale', 'filled_sparse_dsi', 'sparse_dsi_grids'],
    '_reference': ['sparse_joint_bilateral_reference', 'filled_sparse_dsi_reference'],
    '_lowpass': ['gaussian_taps', 'lowpass_interpolation', 'gaussian_lowpass', 'block_lowpass', 'upsample_block_means'],
})

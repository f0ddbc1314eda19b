"""Recovering the right image from the left image and the disparity (the warp for the right image)."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_synthesis': ['WARP_MODES', 'DEFAULT_WARP_MODE', 'DEFAULT_Z_TOLERANCE', 'DEFAULT_ENHANCE_SIGMA_S_PER_STRIDE', 'DEFAULT_ENHANCE_SIGMA_R', 'DEFAULT_ENHANCE_SHRINKAGE', 'ENHANCE_GRID_CELLS_PER_SIGMA', 'warp_left_to_right', 'sample_arrays', 'interpolate_samples', 'inpaint_from_samples', 'enhance_with_samples', 'RecoveredRight', 'check_recovery_inputs', 'BLOCK_MEAN_ITERATIONS', 'recover_right_from_block_means', 'recover_right'],
    '_reference': ['warp_reference'],
})

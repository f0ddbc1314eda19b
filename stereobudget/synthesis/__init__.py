"""Recovering the right image from the left image and the disparity: the warp, the inpainting from the samples,
the enhancement with the samples (one module each), chained by :func:`recover_right` with a :class:`SynthesisParams`."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_warp': ['WARP_MODES', 'DEFAULT_WARP_MODE', 'DEFAULT_Z_TOLERANCE', 'warp_left_to_right'],
    '_inpaint': ['sample_arrays', 'interpolate_samples', 'inpaint_from_samples'],
    '_enhance': ['DEFAULT_ENHANCE_SIGMA_S_PER_STRIDE', 'DEFAULT_ENHANCE_SIGMA_R', 'DEFAULT_ENHANCE_SHRINKAGE',
                 'ENHANCE_GRID_CELLS_PER_SIGMA', 'enhance_with_samples'],
    '_recover': ['SynthesisParams', 'RecoveredRight', 'check_recovery_inputs', 'BLOCK_MEAN_ITERATIONS',
                 'recover_right_from_block_means', 'recover_right'],
    '_reference': ['warp_reference'],
})

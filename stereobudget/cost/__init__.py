"""Matching costs: truncated absolute differences and gradients, census and lattice census, noise level, the dense DSI."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_census': ['CENSUS_RADIUS', 'CENSUS_BITS', 'census_transform', 'census_cost_volume', 'census_cost_volume_reference', 'spaced_census', 'lattice_census', 'mix_spaced_census'],
    '_cost': ['DEFAULT_TRUNCATION', 'to_float_image', 'LUMA_WEIGHTS', 'to_gray', 'float_and_gray', 'pixel_cost', 'sparse_pair_cost', 'sample_row_steps', 'reversed_right_row', 'dense_pixel_costs', 'horizontal_gradient', 'gradient_at', 'gradient_sources', 'full_dsi', 'noise_level', 'noise_level_of_gray'],
    '_reference': ['full_dsi_reference'],
    '_layers': ['LAYER_QUANTUM', 'volume_layers'],
    '_sparse': ['SparseCostTerms', 'SparseTerms', 'RightSamples', 'LeftPixels', 'left_terms', 'left_terms_at', 'bilinear_at',
                'sample_cost'],
})

"""Where the right camera samples: regular, random, adaptive and farthest-point patterns; block means."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_patterns': ['PATTERN_KINDS', 'SamplingPattern', 'grid_shape', 'sample_count', 'splitmix64', 'ADAPTIVE_DIVISOR', 'ADAPTIVE_BASE', 'adaptive_split', 'adaptive_tile_weights', 'fps_positions', 'adaptive_fps_positions', 'downsample_shape', 'downsample_blocks', 'sample_positions'],
    '_fps': ['BLOCK', 'FarthestPointSampler'],
})

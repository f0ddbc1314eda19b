"""The decoders of paper Fig. 2 (sparse, hybrid, downsample, full), their parameters, tiling and memory."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_decoders': ['DecoderParams', 'DecodeResult', 'check_inputs', 'adapt_to_noise', 'hybrid_weight', 'decode', 'DEFAULT_TILE_OVERLAP', 'MIN_TILE_ROWS', 'TILED_METHODS', 'auto_tile_rows', 'decode_tiled'],
    '_methods': ['METHODS', 'DEFAULT_METHOD'],
})

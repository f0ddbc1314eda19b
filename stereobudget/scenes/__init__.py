"""Synthetic stereo scenes with exact ground truth, for tests and demos."""

from .._lazy import attach

__getattr__, __dir__, __all__ = attach(__name__, {
    '_scenes': ['SCENE_KINDS', 'SyntheticScene', 'make_scene'],
})

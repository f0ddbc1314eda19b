"""Plane refinement against its plain reference, and what it does to terraces, rejected pixels and
planes the samples contradict (synthetic slants with exact ground truth)."""

import numpy as np
import pytest

from stereobudget.aggregate import (fit_segment_planes, plane_refinement, plane_refinement_reference,
                                    segment_image)
from stereobudget.cost import to_gray
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


def _scene(kind="slanted", seed=0):
    scene = make_scene(kind, height=72, width=96, max_disp=16, seed=seed)
    gray = to_gray(scene.left.astype(np.float32))
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 3, 3))
    return scene, gray, samples


def _degraded(scene, seed):
    """Terraces (winners rounded to whole pixels), and a quarter of the pixels rejected with junk values."""
    rng = np.random.default_rng(seed)
    disparity = np.round(scene.disparity).astype(np.float32)
    confident = rng.random(disparity.shape) > 0.25
    disparity[~confident] = rng.uniform(0, scene.max_disp, int((~confident).sum()))
    return disparity, confident


@pytest.mark.parametrize("kind", ["slanted", "ground_plane", "weak_texture"])
@pytest.mark.parametrize("options", [{}, {"coarse_size": 30}, {"replace_confident": False},
                                     {"snap_tolerance": 1.0, "anchored": False}])
@pytest.mark.parametrize("with_samples", [True, False])
def test_matches_reference(kind, options, with_samples):
    scene, gray, samples = _scene(kind)
    disparity, confident = _degraded(scene, 1)
    kwargs = dict(samples=samples if with_samples else None, min_disp=0, max_disp=scene.max_disp, size=10, **options)
    fast = plane_refinement(disparity, confident, gray, **kwargs)
    reference = plane_refinement_reference(disparity, confident, gray, **kwargs)
    assert fast.dtype == np.float32 and fast.shape == disparity.shape
    # Centre means summed in another order may move a tie of the segmentation: allow a few pixels.
    close = np.abs(fast - reference) <= 1e-3
    assert close.mean() > 0.99


def test_segments_follow_grey_level_edges():
    gray = np.full((40, 40), 60.0, np.float32)
    gray[:, 17:] = 200.0                                   # an edge off the seed grid's cell borders
    labels = segment_image(gray, size=10, compactness=10.0)
    assert labels.shape == gray.shape and labels.dtype == np.int32
    # No segment holds pixels of both sides.
    left, right = set(np.unique(labels[:, :17])), set(np.unique(labels[:, 17:]))
    assert not left & right


def test_plane_fit_ignores_outliers():
    y, x = np.mgrid[0:30, 0:30]
    truth = (0.2 * x - 0.1 * y + 7.0).astype(np.float32)
    disparity = truth.copy()
    disparity[::4, ::3] += 6.0                             # another surface's pixels in the segment
    labels = np.zeros((30, 30), np.int32)
    planes, inliers, counts, sizes = fit_segment_planes(disparity, np.ones((30, 30), bool), labels)
    # Cauchy weights leave the outliers a little pull (1 / 145 each at the last scale).
    np.testing.assert_allclose(planes[0], [0.2, -0.1, 7.0], atol=0.02)
    assert counts[0] == sizes[0] == 900 and inliers[0] == 900 - disparity[::4, ::3].size


@pytest.mark.parametrize("kind", ["slanted", "ground_plane"])
def test_terraces_and_rejected_pixels_take_the_plane(kind):
    scene, gray, samples = _scene(kind)
    disparity, confident = _degraded(scene, 2)
    before = np.abs(disparity - scene.disparity)[scene.nonocc]
    out = plane_refinement(disparity, confident, gray, samples=samples, min_disp=0, max_disp=scene.max_disp)
    after = np.abs(out - scene.disparity)[scene.nonocc]
    assert np.mean(after > 1) < 0.4 * np.mean(before > 1)     # what is left: segments across depth edges
    # The terraces were up to half a pixel off; the planes are closer.
    assert np.median(after) < 0.7 * np.median(before)


def test_samples_veto_a_plane_they_contradict():
    scene, gray, samples = _scene("slanted", seed=3)
    y = np.arange(scene.disparity.shape[0])[:, None]
    # The rows that carry samples are rejected but right; the others agree on a wrong plane.
    confident = np.broadcast_to(y % 3 != 0, scene.disparity.shape).copy()
    disparity = np.where(confident, scene.disparity + 3.0, scene.disparity).astype(np.float32)
    # Whole rows rejected have no confident pixel of their own row to anchor a plane: not asked here.
    args = dict(min_disp=0, max_disp=scene.max_disp + 3, anchored=False)
    blind = plane_refinement(disparity, confident, gray, samples=None, **args)
    checked = plane_refinement(disparity, confident, gray, samples=samples, **args)
    rows = (~confident) & scene.nonocc
    assert np.median(np.abs(blind - scene.disparity)[rows]) > 2.0     # the plane alone takes the wrong value
    assert np.median(np.abs(checked - scene.disparity)[rows]) < 0.1   # the samples keep the right one

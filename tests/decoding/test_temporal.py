"""A temporal Decoder on a short synthetic stream: the first frame and a scene cut search the whole
range, a coherent frame a band around the previous disparities, a frame whose disparities leave
the band is decoded again on the whole range, and a frame of another size is an error naming it."""

from __future__ import annotations

import numpy as np
import pytest

from stereobudget.decoding import Decoder, TemporalParams, decode
from stereobudget.errors import MismatchError
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene

H, W, PAN, MAX_DISP = 72, 112, 2, 40
GRID = SamplingPattern("grid", 5, 5)


def crop(scene, left_at, right_at=None):
    right_at = left_at if right_at is None else right_at
    return (np.ascontiguousarray(scene.left[:, left_at:left_at + W]),
            encode_image(np.ascontiguousarray(scene.right[:, right_at:right_at + W]), pattern=GRID))


@pytest.fixture(scope="module")
def scenes():
    # Disparities 0-16 of a 0-40 search: a band around them is well under the whole range.
    return (make_scene("slanted", height=H, width=W + 40, max_disp=16, seed=3),
            make_scene("planes", height=H, width=W, max_disp=16, seed=4))


def bad(disparity, scene, at, shift=0):
    gt = scene.disparity[:, at:at + W] + shift
    nonocc = scene.nonocc[:, at:at + W] & (np.arange(W)[None, :] - gt >= 0)
    return float(np.mean(~(np.abs(disparity - gt)[nonocc] <= 1.0)))


def test_a_stream_searches_a_band_and_the_whole_range_where_it_must(scenes):
    pan, other = scenes
    with Decoder(temporal=True) as decoder:
        first = decoder.decode(*crop(pan, 0), max_disp=MAX_DISP)
        assert first.stream == {"frame": 0, "searched": (0, MAX_DISP), "reason": "first"}
        assert (first.min_disp, first.max_disp) == (0, MAX_DISP)
        np.testing.assert_array_equal(first.disparity, decode(*crop(pan, 0), max_disp=MAX_DISP).disparity)

        # A coherent frame (the view pans 2 px): a band, as accurate as the whole range.
        second = decoder.decode(*crop(pan, PAN), max_disp=MAX_DISP)
        low, high = second.stream["searched"]
        assert second.stream["reason"] == "band" and second.stream["frame"] == 1
        assert 0 <= low and high < MAX_DISP and high - low + 1 <= 0.75 * (MAX_DISP + 1)
        assert (second.min_disp, second.max_disp) == (0, MAX_DISP)
        valid = second.disparity[np.isfinite(second.disparity)]
        assert valid.min() >= low and valid.max() <= high
        whole = decode(*crop(pan, PAN), max_disp=MAX_DISP).disparity
        assert bad(second.disparity, pan, PAN) <= bad(whole, pan, PAN) + 0.01

        # The range changes: the right view moves 14 px, every disparity grows by 14 and
        # leaves the band; the frame is decoded on the whole range, as a plain decode does.
        moved = decoder.decode(*crop(pan, 2 * PAN, 2 * PAN + 14), max_disp=MAX_DISP)
        assert moved.stream["reason"] in ("edge", "cut") and moved.stream["searched"] == (0, MAX_DISP)
        np.testing.assert_array_equal(moved.disparity,
                                      decode(*crop(pan, 2 * PAN, 2 * PAN + 14), max_disp=MAX_DISP).disparity)
        assert bad(moved.disparity, pan, 2 * PAN, shift=14) < 0.25

        # A scene cut: another scene, the whole range.
        cut = decoder.decode(*crop(other, 0), max_disp=MAX_DISP)
        assert cut.stream["reason"] == "cut" and cut.stream["searched"] == (0, MAX_DISP)

        # The caller's range changes (as an estimated one does): the band, cut to the new range...
        narrower = decoder.decode(*crop(other, 0), max_disp=32)
        assert narrower.stream["reason"] == "band" and narrower.stream["searched"][1] <= 32
        assert (narrower.min_disp, narrower.max_disp) == (0, 32)
        # ... unless the new range holds none of the previous disparities.
        away = decoder.decode(*crop(other, 0), min_disp=30, max_disp=40)
        assert away.stream == {"frame": 5, "searched": (30, 40), "reason": "range"}

        # Another frame size: an error naming the frame; reset() starts a new stream.
        small = make_scene("slanted", height=40, width=64, max_disp=8, seed=5)
        samples = encode_image(small.right, pattern=GRID)
        with pytest.raises(MismatchError, match="frame 6 is 64x40, the stream's frames are 112x72"):
            decoder.decode(small.left, samples, max_disp=8)
        decoder.reset()
        assert decoder.decode(small.left, samples, max_disp=8).stream["reason"] == "first"


def test_an_edge_share_of_zero_never_keeps_a_band_with_winners_on_its_edge(scenes):
    pan, _ = scenes
    with Decoder(temporal=TemporalParams(edge_share=0.0, margin=0.0, min_margin=0)) as decoder:
        decoder.decode(*crop(pan, 0), max_disp=MAX_DISP)
        second = decoder.decode(*crop(pan, PAN), max_disp=MAX_DISP)
    low, high = second.stream["searched"]
    valid = second.disparity[np.isfinite(second.disparity)]
    if second.stream["reason"] == "band":
        assert not np.any((valid <= low + 0.5) & (low > 0)) and not np.any((valid >= high - 0.5) & (high < MAX_DISP))
    else:
        assert second.stream["reason"] == "edge" and (low, high) == (0, MAX_DISP)

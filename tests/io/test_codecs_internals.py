"""White-box tests of stereobudget.io._codecs: bit packing, the PNG row filters, and an installation
without JPEG XL (``have_jxl`` patched to answer no)."""

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereobudget.errors import OptionError, UnsupportedVersionError
from stereobudget.io import _codecs
from stereobudget.io import read_samples, write_samples
from stereobudget.encoding import encode_image, fit_budget
from stereobudget.sampling import SamplingPattern

needs_jxl = pytest.mark.skipif(not _codecs.have_jxl(), reason="imagecodecs with JPEG XL is not installed")


def noise_image(h, w, dtype):
    """Uniform noise: no codec makes it smaller than raw."""
    return np.random.default_rng(0).integers(0, np.iinfo(dtype).max, (h, w, 3), endpoint=True, dtype=dtype)


def ramp_image(h, w):
    """A smooth 8-bit RGB ramp: every lossless codec makes it smaller than raw."""
    ramp = (np.add.outer(np.arange(h), 2 * np.arange(w)) % 256).astype(np.uint8)
    return np.stack([ramp, ramp[::-1], ramp[:, ::-1]], axis=2)


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 16), st.lists(st.integers(0, 65535), min_size=0, max_size=40))
def test_bit_packing_round_trips(bits, values):
    flat = (np.array(values, np.uint16) >> (16 - bits)).astype(np.uint16)
    packed = _codecs.pack_bits(flat, bits)
    assert len(packed) == -(-flat.size * bits // 8)
    np.testing.assert_array_equal(_codecs.unpack_bits(packed, flat.size, bits, np.uint16), flat)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 9), st.integers(1, 9), st.sampled_from([1, 3]), st.sampled_from([np.uint8, np.uint16]),
       st.integers(0, 2 ** 32 - 1))
def test_png_filters_invert_exactly(rows, cols, channels, dtype, seed):
    rng = np.random.default_rng(seed)
    top = np.iinfo(dtype).max
    image = rng.integers(0, top + 1, (rows, cols, channels)).astype(dtype)
    payload = zlib.compress(_codecs.png_filter(image))
    back = _codecs.decode_payload(payload, codec="deflate", value_bits=8 * np.dtype(dtype).itemsize,
                                  count=rows * cols, channels=channels, lattice=(rows, cols),
                                  channel_order="gray" if channels == 1 else "rgb")
    np.testing.assert_array_equal(back.reshape(image.shape), image)


def test_lossless_means_jpeg_xl_and_falls_back_to_webp(monkeypatch):
    if _codecs.have_jxl():
        assert _codecs.resolve_codec("lossless") == "jxl_lossless"
    monkeypatch.setattr(_codecs, "have_jxl", lambda: False)
    assert _codecs.resolve_codec("lossless") == "webp_lossless"
    with pytest.raises(OptionError, match="imagecodecs"):
        _codecs.resolve_codec("jxl")


@needs_jxl
def test_a_jpeg_xl_file_without_imagecodecs_is_an_unsupported_version(monkeypatch):
    data = write_samples(encode_image(ramp_image(61, 83), pattern=SamplingPattern("grid", 3, 3)),
                         codec="jxl_lossless")
    monkeypatch.setattr(_codecs, "have_jxl", lambda: False)
    with pytest.raises(UnsupportedVersionError, match="needs imagecodecs"):
        read_samples(data)


def test_the_default_budget_search_skips_codings_that_cannot_apply(monkeypatch):
    monkeypatch.setattr(_codecs, "have_jxl", lambda: False)       # lossless = WebP: 8 bits only
    img = noise_image(60, 80, np.uint16)
    ss, data, coding = fit_budget(img, budget=3000)
    assert len(data) <= 3000 and coding["codec"] == "raw"

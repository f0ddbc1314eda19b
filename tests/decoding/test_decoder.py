"""Plain decode() leaves the process alone; a Decoder opts in to memory handed between decodes."""

import numpy as np
import pytest

import stereobudget
from stereobudget._kernels import _scratch as scratch
from stereobudget.decoding import Decoder, DecoderParams, decode, shared_decoder
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.scenes import make_scene


@pytest.fixture(scope="module")
def scene():
    return make_scene("slanted", height=48, width=64, max_disp=12, seed=3)


class _FakeLibc:
    """Stands in for glibc: records mallopt / malloc_trim calls instead of making them."""

    def __init__(self):
        self.calls = []

    def mallopt(self, param, value):
        self.calls.append(("mallopt", param, value))
        return 1

    def malloc_trim(self, pad):
        self.calls.append(("malloc_trim", pad))
        return 1


@pytest.fixture
def libc(monkeypatch):
    """A fresh process's view: nothing kept, the allocator untuned, glibc faked."""
    fake = _FakeLibc()
    scratch.release()
    monkeypatch.setattr(scratch._frames, "keepers", 0)          # a shared decoder of other tests: not ours
    monkeypatch.setattr(scratch, "_malloc_tuned", [])
    monkeypatch.setattr(scratch.ctypes, "CDLL", lambda name: fake)
    monkeypatch.setattr(scratch.sys, "platform", "linux")
    monkeypatch.delenv("STEREOBUDGET_KEEP_FREED_MEMORY", raising=False)
    yield fake
    scratch.release()


CASES = [("hybrid", "grid", 4, {}), ("sparse", "grid", 4, {}), ("hybrid", "grid", 4, {"hybrid_aggregation": "tree"}),
         ("sparse", "jitter", 4, {}), ("downsample", "downsample", 4, {}), ("full", "grid", 1, {})]


def test_plain_decode_holds_no_memory_and_leaves_the_allocator_alone(scene, libc):
    for method, kind, stride, changes in CASES:
        samples = encode_image(scene.right, pattern=SamplingPattern(kind, stride, stride))
        decode(scene.left, samples, max_disp=12, method=method, params=DecoderParams(**changes))
        assert scratch.spare_bytes() == 0, method
        if method != "downsample":                           # and in bands
            decode(scene.left, samples, max_disp=12, method=method, tile_rows=20, tile_overlap=8)
            assert scratch.spare_bytes() == 0, method
    assert libc.calls == []


def test_a_decoder_reuses_its_volumes_and_gives_them_back(scene, libc, monkeypatch):
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    taken = []
    take = scratch._take_spare

    def counting_take(size):
        spare = take(size)
        taken.append(spare is not None)
        return spare

    monkeypatch.setattr(scratch, "_take_spare", counting_take)
    with Decoder() as decoder:
        assert [call[0] for call in libc.calls] == ["mallopt", "mallopt"]   # tuned once, on opening
        for method in ("hybrid", "sparse"):
            first = decoder.decode(scene.left, samples, max_disp=12, method=method).disparity
            assert scratch.spare_bytes() > 0, "the decode handed its volumes back"
            for _, spare in scratch._spare:
                spare.fill(np.nan)                         # poison: any value not rewritten shows
            taken.clear()
            second = decoder.decode(scene.left, samples, max_disp=12, method=method).disparity
            assert any(taken), "the second decode ran on the first one's volumes"
            np.testing.assert_array_equal(first, second)
        with Decoder(keep_freed_memory=False):             # nested: the pools stay until the last closes
            pass
        assert scratch.spare_bytes() > 0
    assert scratch.spare_bytes() == 0 and not decoder.is_open
    assert libc.calls[-1] == ("malloc_trim", 0) and len(libc.calls) == 3
    decoder.close()                                        # closing twice is harmless


def test_decodes_are_bit_identical_with_and_without_a_decoder(scene, libc):
    for method, kind, stride, changes in CASES:
        samples = encode_image(scene.right, pattern=SamplingPattern(kind, stride, stride))
        options = dict(max_disp=12, method=method, params=DecoderParams(**changes))
        plain = decode(scene.left, samples, **options).disparity
        with Decoder() as decoder:
            kept = [decoder.decode(scene.left, samples, **options).disparity for _ in range(2)]
        for disparity in kept:
            np.testing.assert_array_equal(plain, disparity, err_msg=method)


def test_the_decoder_is_public_at_the_top_level_and_the_shared_one_stays_open():
    assert stereobudget.Decoder is Decoder
    assert shared_decoder() is shared_decoder() and shared_decoder().is_open


def test_without_kept_memory_a_decoder_keeps_only_the_small_volumes(scene, libc, monkeypatch):
    monkeypatch.setenv("STEREOBUDGET_KEEP_FREED_MEMORY", "0")
    monkeypatch.setattr(scratch, "LARGE_BYTES", 128 * 1024)    # the 192 KiB cost volume is "large", grids not
    samples = encode_image(scene.right, pattern=SamplingPattern("grid", 4, 4))
    with Decoder() as decoder:
        decoder.decode(scene.left, samples, max_disp=12, method="sparse")
        assert scratch._large == [] and scratch._spare
    assert libc.calls == []

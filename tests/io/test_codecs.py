"""Payload coding (.sbs 1.1): every codec round-trips, corrupt coded payloads are refused."""

import struct
import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stereobudget.errors import CorruptHeaderError, CorruptPayloadError, OptionError, UnsupportedVersionError
from stereobudget import io as sbio
from stereobudget.io import probe, read_samples, write_samples
from stereobudget.encoding import BUDGET_DROPPED_BITS, encode_image, fit_budget
from stereobudget.sampling import SamplingPattern

HEADER = sbio.HEADER_SIZE_V1_0
# The coding block of docs/format.md at offset 40: codec, value bits, quality, zero, values CRC-32, reserved.
CODING_BLOCK = struct.Struct("<BBBBI8s")
LOSSLESS = ("raw", "deflate", "webp_lossless", "jxl_lossless")
needs_jxl = pytest.mark.skipif(not sbio.have_jxl(), reason="imagecodecs with JPEG XL is not installed")


def smooth_image(h=61, w=83, channels=3, dtype=np.uint8, seed=0):
    """Smooth texture plus a little noise: what codecs are made for, not trivially compressible."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.stack([128 + 90 * np.sin(xx / (7 + c) + yy / (11 + 2 * c)) for c in range(channels)], axis=-1)
    img += rng.normal(0, 3, img.shape)
    top = np.iinfo(dtype).max
    img = np.clip(img / 255 * top, 0, top).astype(dtype)
    return img[:, :, 0] if channels == 1 else img


def grid(stride=3, **kw):
    return SamplingPattern(kind="grid", stride_x=stride, stride_y=stride, **kw)


def codec_available(codec):
    return not codec.startswith("jxl") or sbio.have_jxl()


CASES = [(codec, ch, dt, order) for codec in ("raw", "deflate", "webp_lossless", "jxl_lossless", "webp", "jxl")
         for ch in (1, 3) for dt in (np.uint8, np.uint16) for order in (("natural", "bgr") if ch == 3 else ("natural",))]


@pytest.mark.parametrize("codec,channels,dtype,order", CASES)
def test_every_codec_round_trips(codec, channels, dtype, order):
    if not codec_available(codec):
        pytest.skip("imagecodecs with JPEG XL is not installed")
    img = smooth_image(channels=channels, dtype=dtype)
    channel_order = "bgr" if order == "bgr" else ("gray" if channels == 1 else "rgb")
    ss = encode_image(img, pattern=grid(3, offset_x=1, offset_y=2), channel_order=channel_order)
    # WebP holds 8 bits: 16-bit samples keep their top 8 (lossy webp needs exactly 8).
    bits = 8 if codec.startswith("webp") and dtype == np.uint16 else None
    data = write_samples(ss, codec=codec, value_bits=bits)
    back = read_samples(data)
    info = probe(data, verify_payload=True)
    assert back.pattern == ss.pattern and back.channel_order == channel_order
    full = 8 * np.dtype(dtype).itemsize
    kept = full if bits is None else bits
    tolerance = 0 if kept == full else 2 ** (full - kept - 1)
    err = np.abs(back.values.astype(np.int64) - ss.values.astype(np.int64))
    if codec in sbio.LOSSY_CODECS and info["codec"] != "raw":
        # Stated error of the lossy codecs at the default quality 90, on a smooth image:
        # PSNR of the lattice at least 30 dB (in units of the full range).
        mse = np.mean((err / (2 ** full - 1) * 255.0) ** 2)
        assert 10 * np.log10(255.0 ** 2 / max(mse, 1e-12)) >= 30
        assert info["quality"] == 90 and not back.exact
    else:
        assert err.max() <= tolerance
        assert back.exact == (tolerance == 0)
    # Raw full-depth files (also a coded payload that fell back to raw) stay 1.0.
    assert data[9] == (0 if info["codec"] == "raw" and kept == full else 1)
    assert info["codec"] in (codec, "raw")
    if codec in ("jxl_lossless", "jxl", "webp_lossless") and dtype == np.uint8:
        assert info["codec"] == codec, "a smooth 8-bit lattice codes shorter than raw"


def test_raw_full_depth_is_the_1_0_file_byte_for_byte():
    ss = encode_image(smooth_image(), pattern=grid(5))
    data = write_samples(ss, codec="raw")
    assert data == write_samples(ss)
    assert data[8:10] == b"\x01\x00" and data[40:56] == bytes(16)
    assert data[HEADER:] == ss.values.tobytes()


@pytest.mark.parametrize("bits", [1, 3, 5, 7, 8])
@pytest.mark.parametrize("pattern", ["grid", "jitter", "fps", "downsample"])
def test_dropped_bits_round_trip_within_half_a_step_on_every_pattern(bits, pattern):
    img = smooth_image(h=30, w=40)
    p = SamplingPattern(kind=pattern, stride_x=3, stride_y=3, seed=0 if pattern in ("grid", "downsample") else 5)
    ss = encode_image(img, pattern=p)
    data = write_samples(ss, value_bits=bits)
    n = ss.values.size
    assert len(data) - HEADER == -(-n * bits // 8)
    back = read_samples(data)
    assert back.value_bits == (None if bits == 8 else bits)
    err = np.abs(back.values.astype(int) - ss.values.astype(int))
    assert err.max() <= (2 ** (8 - bits - 1) if bits < 8 else 0)
    # The restored value is the middle of the interval the camera's value lies in.
    np.testing.assert_array_equal(back.values >> (8 - bits), ss.values >> (8 - bits))


def test_a_coded_payload_no_shorter_than_raw_is_written_raw():
    noise = np.random.default_rng(1).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    ss = encode_image(noise, pattern=grid(1))
    data = write_samples(ss, codec="deflate")
    assert data == write_samples(ss) and probe(data)["codec"] == "raw"
    data = write_samples(ss, codec="deflate", value_bits=8 - 1)
    assert probe(data)["codec"] in ("raw", "deflate")
    assert len(data) - HEADER <= -(-ss.values.size * 7 // 8)


@pytest.mark.parametrize("pattern", ["jitter", "fps", "adaptive_fps"])
@pytest.mark.parametrize("codec", ["deflate", "webp_lossless", "lossless", "webp"])
def test_image_codecs_refuse_scattered_samples(pattern, codec):
    ss = encode_image(smooth_image(h=20, w=20), pattern=SamplingPattern(kind=pattern, stride_x=4, stride_y=4, seed=1))
    with pytest.raises(OptionError, match="needs a lattice pattern"):
        write_samples(ss, codec=codec)


def test_option_errors_name_the_problem():
    ss8 = encode_image(smooth_image(), pattern=grid())
    ss16 = encode_image(smooth_image(dtype=np.uint16), pattern=grid())
    with pytest.raises(OptionError, match="between 1 and 8"):
        write_samples(ss8, value_bits=9)
    with pytest.raises(OptionError, match="8-bit values"):
        write_samples(ss16, codec="webp_lossless")
    with pytest.raises(OptionError, match="unknown codec"):
        write_samples(ss8, codec="gif")
    with pytest.raises(OptionError, match="lossy webp"):
        write_samples(ss8, codec="webp", value_bits=6)


# --- corrupt coded files ------------------------------------------------------------------

def with_coding(data: bytes, *, payload: bytes | None = None, **changes) -> bytes:
    """``data`` with coding-block fields / payload replaced and both CRCs recomputed."""
    codec, bits, quality, zero, crc, rest = CODING_BLOCK.unpack_from(data, 40)
    block = dict(codec=codec, value_bits=bits, quality=quality, zero=zero, crc=crc, rest=rest)
    block.update(changes)
    payload = data[HEADER:] if payload is None else payload
    head = bytearray(data[:76])
    head[40:56] = CODING_BLOCK.pack(*block.values())
    struct.pack_into("<QI", head, 64, len(payload), zlib.crc32(payload) & 0xFFFFFFFF)
    return bytes(head) + struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF) + payload


def coded_files():
    img = smooth_image()
    files = {}
    for codec in ("deflate", "webp_lossless", "jxl_lossless", "webp", "jxl"):
        if codec_available(codec):
            files[codec] = write_samples(encode_image(img, pattern=grid()), codec=codec)
    files["raw6"] = write_samples(encode_image(img, pattern=grid()), value_bits=6)
    return files


@pytest.mark.parametrize("codec", ["deflate", "webp_lossless", "jxl_lossless", "webp", "jxl", "raw6"])
def test_damaged_coded_payloads_are_corrupt_payloads(codec):
    files = coded_files()
    if codec not in files:
        pytest.skip("imagecodecs with JPEG XL is not installed")
    data = files[codec]
    assert probe(data)["codec"] == codec.rstrip("6")
    payload = bytearray(data[HEADER:])
    # Without the CRC fixed, the payload checksum catches any damage.
    damaged = data[:HEADER] + bytes([payload[0] ^ 0x40]) + bytes(payload[1:])
    with pytest.raises(CorruptPayloadError, match="payload checksum"):
        read_samples(damaged)
    # With it fixed, the codec (or the values checksum) must still refuse, or decode a
    # valid lattice (lossy codecs have nothing to compare with): never anything else.
    rng = np.random.default_rng(0)
    for _ in range(30):
        mutated = bytearray(payload)
        for pos in rng.integers(0, len(mutated), 3):
            mutated[pos] ^= 1 << int(rng.integers(0, 8))
        try:
            back = read_samples(with_coding(data, payload=bytes(mutated)))
        except CorruptPayloadError:
            continue
        assert codec in sbio.LOSSY_CODECS, "damage to a lossless payload went unnoticed"
        assert back.values.shape == read_samples(data).values.shape
    for cut in (0, 1, len(payload) // 2):
        with pytest.raises(CorruptPayloadError):
            read_samples(with_coding(data, payload=bytes(payload[:cut])))


@pytest.mark.parametrize("codec", ["webp_lossless", "webp", "jxl_lossless", "jxl"])
def test_an_image_of_another_size_is_refused_before_it_is_decoded(codec):
    if not codec_available(codec):
        pytest.skip("imagecodecs with JPEG XL is not installed")
    img = smooth_image()
    data = write_samples(encode_image(img, pattern=grid(3)), codec=codec)
    other = write_samples(encode_image(img, pattern=grid(4)), codec=codec)[HEADER:]
    with pytest.raises(CorruptPayloadError, match="a 21x16 image, expected the 28x21 lattice|out.shape"):
        read_samples(with_coding(data, payload=other, crc=0))


def test_coding_block_errors_have_their_classes():
    data = coded_files()["deflate"]
    with pytest.raises(UnsupportedVersionError, match="payload codec 9"):
        read_samples(with_coding(data, codec=9))
    with pytest.raises(CorruptHeaderError, match="value_bits 12"):
        read_samples(with_coding(data, value_bits=12))
    with pytest.raises(CorruptHeaderError, match="quality 50"):
        read_samples(with_coding(data, quality=50))
    with pytest.raises(CorruptHeaderError, match="quality 0"):
        read_samples(with_coding(data, codec=4))
    with pytest.raises(CorruptPayloadError, match="do not match their checksum"):
        read_samples(with_coding(data, crc=1234))
    raw = write_samples(encode_image(smooth_image(), pattern=grid()))
    with pytest.raises(CorruptPayloadError, match="shorter than the"):
        read_samples(with_coding(raw[:9] + b"\x01" + raw[10:], codec=1))
    fps = write_samples(encode_image(smooth_image(), pattern=SamplingPattern(kind="fps", stride_x=3, stride_y=3)))
    with pytest.raises(CorruptHeaderError, match="needs a lattice pattern"):
        read_samples(with_coding(fps[:9] + b"\x01" + fps[10:], codec=1, payload=b"x"))


def test_1_0_files_still_read_whatever_their_reserved_bytes():
    # The example file of docs/format.md, byte for byte.
    spec = bytes.fromhex(
        "89534253 0d0a1a0a 01005000 04000000 03000000 01000200 02000200 01000000"
        "00000000 00000000 00000000 00000000 00000000 00000000 04000000 00000000"
        "08000000 00000000 2286e5dd 0b150334 e803b80b 2823f82a")
    back = read_samples(spec)
    assert back.values.ravel().tolist() == [1000, 3000, 9000, 11000] and back.codec == "raw" and back.exact
    head = bytearray(spec[:76])
    head[40] = 3          # a codec id, but 1.0 readers ignore the reserved bytes
    odd = bytes(head) + struct.pack("<I", zlib.crc32(head)) + spec[80:]
    assert read_samples(odd).values.ravel().tolist() == [1000, 3000, 9000, 11000]
    assert probe(odd)["codec"] == "raw"


# --- byte budget -----------------------------------------------------------------------------

@settings(max_examples=25, deadline=None)
@given(st.integers(200, 20000), st.sampled_from([None, "lossless", "deflate", "jxl", "webp"]),
       st.sampled_from([None, 6]))
def test_the_budget_is_never_exceeded(budget, codec, bits):
    if codec is not None and not codec_available(codec) or (codec == "webp" and bits):
        return
    img = smooth_image(h=90, w=120)
    try:
        ss, data, coding = fit_budget(img, budget=budget, codec=codec, value_bits=bits)
    except OptionError as exc:
        assert "fits in" in str(exc)
        # Even the sparsest raw grid is over budget.
        assert budget < HEADER + -(-3 * 2 * 2 * (8 if bits is None else bits) // 8)
        return
    assert len(data) <= budget
    back = read_samples(data)
    assert back.pattern.stride_x == ss.pattern.stride_x
    s = ss.pattern.stride_x
    if s > 1 and codec is None:
        # Densest: the next denser grid fits neither raw nor lossless (nor, without --bits,
        # lossless with up to BUDGET_DROPPED_BITS low bits dropped, except at stride 1).
        denser = encode_image(img, pattern=grid(s - 1))
        dropped = 0 if s - 1 == 1 else BUDGET_DROPPED_BITS
        tries = ([("raw", bits), ("lossless", bits)] if bits else
                 [("raw", None)] + [("lossless", b) for b in range(8, 8 - dropped - 1, -1)])
        assert all(len(write_samples(denser, codec=c, value_bits=b)) > budget for c, b in tries)
    if bits is None and codec is None:
        assert coding["value_bits"] >= 8 - BUDGET_DROPPED_BITS


@pytest.mark.parametrize("codec", [None, "deflate", "webp"])
def test_a_hinted_budget_search_finds_what_the_full_search_finds(codec):
    images = [smooth_image(h=90, w=120, seed=seed) for seed in range(3)]
    images.append(np.random.default_rng(5).integers(0, 256, (90, 120, 3), dtype=np.uint8))  # incompressible
    for budget in (700, 1500, 3200, 7000):
        choices = []
        for image in images:
            ss, data, coding = fit_budget(image, budget=budget, codec=codec)
            choices.append(({"stride": ss.pattern.stride_x, "coding": coding}, data))
        # Every image's own choice, another image's, and nonsense must all lead to the same file.
        hints = [hint for hint, _ in choices] + [{"stride": 1, "coding": {"codec": "raw"}}, {"stride": 99}, {}]
        for image, (_, data) in zip(images, choices):
            for hint in hints:
                assert fit_budget(image, budget=budget, codec=codec, hint=hint)[1] == data


def test_the_budget_prefers_lossless_density_to_raw():
    img = smooth_image(h=120, w=160)
    raw5 = len(write_samples(encode_image(img, pattern=grid(5))))
    ss, data, coding = fit_budget(img, budget=raw5)
    assert ss.pattern.stride_x <= 5 and len(data) <= raw5
    ss, data, coding = fit_budget(img, budget=raw5, codec="webp")
    assert coding["codec"] == "webp" and ss.pattern.stride_x < 5

"""Robustness: hostile sample files and images, bad options, memory limits, kills mid-write.

Every case must end in a documented error (a StereoBudgetError subclass; on the command
line its exit code, one stderr line, no traceback) or a successful decode -- never any
other exception, a hang, or a damaged output file.  docs/errors.md lists the codes.
"""

from __future__ import annotations

import functools
import io
import json
import os
import random
import signal
import struct
import subprocess
import sys
import time
import tracemalloc
import zlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereobudget import io as sbio
from stereobudget.io import MAGIC, read_samples, write_samples
from stereobudget.encoding import encode_image
from stereobudget.decoding import estimate_decode_memory
from stereobudget.errors import (CorruptHeaderError, ImageReadError, MemoryLimitError, SampleFileError,
                                 StereoBudgetError, TruncatedFileError)
from stereobudget.sampling import SamplingPattern

REPO = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
SB_ENCODE = str(BIN / "sb-encode")
SB_DECODE = str(BIN / "sb-decode")
HEADER = sbio.HEADER_SIZE_V1_0
W, H = 40, 30

#: Exit codes of docs/errors.md.
DOCUMENTED_EXIT_CODES = {0, 1, 2, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 130, 141}


# --- fixtures ------------------------------------------------------------------------------

def _texture(seed: int, height: int, width: int, channels: int, dtype=np.uint8) -> np.ndarray:
    import cv2
    rng = np.random.default_rng(seed)
    coarse = rng.random((height // 4 + 2, width // 4 + 2, channels)).astype(np.float32)
    img = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_LINEAR).reshape(height, width, channels)
    top = np.iinfo(dtype).max
    img = (img * top).astype(dtype)
    return img[:, :, 0] if channels == 1 else img


def _stereo_pair(seed, height, width, channels, dtype=np.uint8, disparity=3):
    wide = _texture(seed, height, width + disparity, channels, dtype)
    return np.ascontiguousarray(wide[:, disparity:]), np.ascontiguousarray(wide[:, :-disparity])


@functools.lru_cache(maxsize=None)
def base_files() -> tuple:
    """(name, sbs bytes, left image) of every pattern / layout / bit depth, 40x30."""
    specs = (("grid3_gray8", "grid", 3, 1, np.uint8), ("grid4_rgb8", "grid", 4, 3, np.uint8),
             ("jitter3_rgb16", "jitter", 3, 3, np.uint16), ("fps4_gray16", "fps", 4, 1, np.uint16),
             ("adaptive3_rgb8", "adaptive_fps", 3, 3, np.uint8),
             ("downsample4_rgb8", "downsample", 4, 3, np.uint8), ("full_gray8", "grid", 1, 1, np.uint8),
             # 1.1 coded payloads
             ("grid2_rgb8_deflate", "grid", 2, 3, np.uint8, {"codec": "deflate"}),
             ("grid2_rgb8_lossless", "grid", 2, 3, np.uint8, {"codec": "lossless"}),
             ("grid2_gray8_webp", "grid", 2, 1, np.uint8, {"codec": "webp", "quality": 70}),
             ("jitter3_rgb8_bits6", "jitter", 3, 3, np.uint8, {"value_bits": 6}))
    out = []
    for i, (name, kind, stride, channels, dtype, *coding) in enumerate(specs):
        left, right = _stereo_pair(i, H, W, channels, dtype)
        seed = 5 if kind in ("jitter", "fps", "adaptive_fps") else 0
        pattern = SamplingPattern(kind=kind, stride_x=stride, stride_y=stride, seed=seed)
        out.append((name, write_samples(encode_image(right, pattern=pattern), **(coding[0] if coding else {})),
                    left))
    return tuple(out)


@pytest.fixture(scope="module")
def left_files(tmp_path_factory):
    from stereobudget.io import write_image
    folder = tmp_path_factory.mktemp("lefts")
    paths = []
    for name, _, left in base_files():
        path = folder / f"{name}.png"
        write_image(path, left, channel_order="gray" if left.ndim == 2 else "rgb")
        paths.append(str(path))
    return paths


# The 1.0 header of docs/format.md after the magic, up to the header CRC: its own copy, so a
# change to the format's layout shows here as a failure rather than passing silently.
HEADER_FIELDS = struct.Struct("<BBHIIBBBBHHHHQ16sQQI")
FIELD_NAMES = ("version_major", "version_minor", "header_length", "width", "height",
               "channels", "channel_order_code", "dtype_code", "pattern_code",
               "stride_x", "stride_y", "offset_x", "offset_y", "seed", "pattern_reserved",
               "sample_count", "payload_length", "payload_crc32")
_WIDTHS = dict(zip(FIELD_NAMES, (1, 1, 2, 4, 4, 1, 1, 1, 1, 2, 2, 2, 2, 8, 16, 8, 8, 4)))


def rewrite_header(data: bytes, *, fix_crc: bool = True, **changes) -> bytes:
    """``data`` with 1.0 header fields replaced (masked to their width), header CRC recomputed."""
    fields = dict(zip(FIELD_NAMES, HEADER_FIELDS.unpack_from(data, len(MAGIC))))
    for key, value in changes.items():
        fields[key] = int(value) & ((1 << (8 * _WIDTHS[key])) - 1)
    head = MAGIC + HEADER_FIELDS.pack(*(fields[k] for k in FIELD_NAMES))
    crc = zlib.crc32(head) & 0xFFFFFFFF if fix_crc else struct.unpack_from("<I", data, HEADER - 4)[0]
    return head + struct.pack("<I", crc) + data[HEADER:]


# --- mutation strategy -----------------------------------------------------------------------

_FIELD_CHOICES = [n for n in FIELD_NAMES if n != "pattern_reserved"]


@st.composite
def mutated_sample_files(draw):
    """(index of the base file, mutated bytes)."""
    index = draw(st.integers(0, len(base_files()) - 1))
    data = base_files()[index][1]
    other = base_files()[draw(st.integers(0, len(base_files()) - 1))][1]
    kind = draw(st.sampled_from(["truncate", "flip", "splice", "field", "dims", "random", "magic_random",
                                 "payload_crc", "insert", "unchanged", "other", "coding"]))
    if kind == "truncate":
        return index, data[:draw(st.integers(0, len(data) - 1))]
    if kind == "flip":
        buf = bytearray(data)
        for pos, bit in draw(st.lists(st.tuples(st.integers(0, len(data) - 1), st.integers(0, 7)),
                                      min_size=1, max_size=8)):
            buf[pos] ^= 1 << bit
        return index, bytes(buf)
    if kind == "splice":
        return index, data[:draw(st.integers(0, len(data)))] + other[draw(st.integers(0, len(other))):]
    if kind == "field":
        name = draw(st.sampled_from(_FIELD_CHOICES))
        value = draw(st.one_of(st.integers(0, 300), st.integers(0, 2 ** 64 - 1),
                               st.sampled_from([65535, 65536, 2 ** 32 - 1, 2 ** 63])))
        return index, rewrite_header(data, fix_crc=draw(st.booleans()), **{name: value})
    if kind == "dims":
        big = st.sampled_from([0, 65535, 65536, 100000, 2 ** 31, 2 ** 32 - 1, 16385, 40000])
        return index, rewrite_header(data, width=draw(big), height=draw(big),
                                     sample_count=draw(st.sampled_from([0, 2 ** 40, 2 ** 63 + 5])))
    if kind == "random":
        return index, draw(st.binary(max_size=200))
    if kind == "magic_random":
        return index, MAGIC + draw(st.binary(max_size=200))
    if kind == "payload_crc":
        payload = bytearray(data[HEADER:])
        payload[draw(st.integers(0, len(payload) - 1))] ^= 0xFF
        return index, rewrite_header(data[:HEADER] + bytes(payload),
                                     payload_crc32=zlib.crc32(payload) & 0xFFFFFFFF)
    if kind == "coding":
        # The 1.1 coding block (codec, value_bits, quality, values CRC), header CRC fixed.
        head = bytearray(data[:HEADER - 4])
        head[9] = draw(st.sampled_from([0, 1, 1, 2]))
        for where, value in draw(st.lists(st.tuples(st.sampled_from([40, 41, 42, 43, 44, 47]),
                                                    st.integers(0, 255)), min_size=1, max_size=3)):
            head[where] = value
        return index, bytes(head) + struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF) + data[HEADER:]
    if kind == "insert":
        pos = draw(st.integers(0, len(data)))
        return index, data[:pos] + draw(st.binary(min_size=1, max_size=16)) + data[pos:]
    if kind == "other":
        return index, other
    return index, data


def reader_outcome(data: bytes) -> str:
    # The header-only probe (sb-encode --info --header-only) sees the same bytes.
    try:
        sbio.probe(data, name="case.sbs")
        probed = "ok"
    except SampleFileError as exc:
        probed = type(exc).__name__
    try:
        read_samples(data, source="case.sbs")
    except StereoBudgetError as exc:
        assert isinstance(exc, SampleFileError), exc
        assert "\n" not in str(exc) and str(exc).startswith("case.sbs: ")
        # Only the payload checksum is beyond the probe.
        assert probed in (type(exc).__name__, "ok")
        return type(exc).__name__
    assert probed == "ok"
    return "ok"


@settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(mutated_sample_files())
def test_reader_fuzz_ends_in_documented_errors(case):
    _, data = case
    reader_outcome(data)     # any other exception fails the test


@settings(max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(case=mutated_sample_files())
def test_decode_path_fuzz_agrees_with_the_reader(case, left_files, tmp_path_factory):
    from stereobudget.pipeline import DecodeJob, decode_file
    from stereobudget.io import read_disparity

    index, data = case
    folder = tmp_path_factory.mktemp("dec")
    sbs = folder / "case.sbs"
    sbs.write_bytes(data)
    expected = reader_outcome(data)
    job = DecodeJob(left=left_files[index], samples=str(sbs), disparity=str(folder / "d.pfm"), max_disp=6)
    try:
        decode_file(job)
        outcome = "ok"
    except StereoBudgetError as exc:
        outcome = type(exc).__name__
    if expected != "ok":
        assert outcome == expected
    else:
        assert outcome in ("ok", "MismatchError", "OptionError")
    if outcome == "ok":
        assert read_disparity(str(folder / "d.pfm")).shape == (H, W)


@functools.lru_cache(maxsize=None)
def encoded_images() -> tuple:
    import cv2
    import tifffile

    from stereobudget.io import encode_image_bytes
    left, _ = _stereo_pair(7, 20, 24, 3)
    ok, jpeg = cv2.imencode(".jpg", left)
    tiff = io.BytesIO()
    tifffile.imwrite(tiff, left.astype(np.uint16) * 257)
    ok, bmp = cv2.imencode(".bmp", left)
    return (encode_image_bytes(left), encode_image_bytes(left[:, :, 0].astype(np.uint16), channel_order="gray"),
            jpeg.tobytes(), tiff.getvalue(), bmp.tobytes())


@settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True)
@given(index=st.integers(0, 4), cut=st.integers(0, 10 ** 6),
       flips=st.lists(st.tuples(st.integers(0, 10 ** 6), st.integers(0, 7)), max_size=6))
def test_image_reader_fuzz_ends_in_image_errors(index, cut, flips):
    from stereobudget.io import read_image
    data = bytearray(encoded_images()[index])
    for pos, bit in flips:
        data[pos % len(data)] ^= 1 << bit
    data = bytes(data[:max(1, cut % (len(data) + 1))]) if cut % 3 == 0 else bytes(data)
    try:
        image, order = read_image(data, name="case.img")
    except ImageReadError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("case.img: ")
        return
    assert image.dtype in (np.uint8, np.uint16) and image.ndim in (2, 3) and order in ("gray", "rgb")


def test_fuzz_script_runs_clean(tmp_path):
    proc = subprocess.run([sys.executable, str(REPO / "scripts" / "fuzz_sample_file.py"), "--max-cases", "40",
                           # Time for a fresh install's kernel compilation too: the cases stop at 40.
                           "--seconds", "480", "--seed", "3", "--cli-every", "10", "--subprocess-every", "1000",
                           "--save-dir", str(tmp_path / "fail"), "--json", str(tmp_path / "r.json")],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["cases"] == 40
    assert sum(result["decode"].values()) == 40
    assert result["decode"].get("ok", 0) > 0 and len(result["decode"]) >= 4
    assert sum(result["cli_runner"].values()) == 4 and sum(result["subprocess"].values()) == 1
    assert not (tmp_path / "fail").exists()


def test_valid_longer_header_of_a_later_minor_version_is_read():
    _, data, _ = base_files()[1]
    fields = dict(zip(FIELD_NAMES, HEADER_FIELDS.unpack_from(data, len(MAGIC))))
    fields.update(version_minor=3, header_length=HEADER + 12)
    head = MAGIC + HEADER_FIELDS.pack(*(fields[k] for k in FIELD_NAMES)) + bytes(12)
    longer = head + struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF) + data[HEADER:]
    assert np.array_equal(read_samples(longer).values, read_samples(data).values)


@pytest.mark.parametrize("width,height", [(100000, 100000), (65535, 65535), (2 ** 32 - 1, 1), (0, 30),
                                          (40, 0), (16385, 16385)])
def test_absurd_dimensions_with_a_valid_crc_are_refused_before_allocating(width, height):
    _, data, _ = base_files()[0]
    # Count and payload length consistent with the claim: only the size check can refuse it.
    bogus = rewrite_header(data[:HEADER], width=width, height=height, sample_count=width * height,
                           payload_length=width * height)
    tracemalloc.start()
    try:
        with pytest.raises(CorruptHeaderError, match="image size"):
            read_samples(bogus, source="bogus.sbs")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


def test_large_but_legal_dimensions_fail_on_the_missing_payload_without_allocating():
    _, data, _ = base_files()[0]
    bogus = rewrite_header(data[:HEADER], width=16384, height=16384, stride_x=1, stride_y=1,
                           sample_count=16384 ** 2, payload_length=16384 ** 2)
    tracemalloc.start()
    try:
        with pytest.raises(TruncatedFileError):
            read_samples(bogus, source="bogus.sbs")
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < 1 << 20


# --- images -------------------------------------------------------------------------------------

def _png_header_only(width: int, height: int) -> bytes:
    def chunk(tag, payload):
        return struct.pack(">I", len(payload)) + tag + payload + struct.pack(">I", zlib.crc32(tag + payload))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
            + chunk(b"IEND", b""))


def test_png_claiming_100000_squared_is_refused_before_decoding():
    # The file holds a header and no pixels: only a check of the header's size can name it.
    with pytest.raises(ImageReadError, match="100000x100000"):
        sbio.read_image(_png_header_only(100000, 100000), name="bomb.png")


@pytest.fixture(scope="module")
def image_cases(tmp_path_factory):
    """Hostile images plus matching/mismatching sample files, all 40x30."""
    import tifffile

    from stereobudget.io import write_image
    d = tmp_path_factory.mktemp("images")
    left, right = _stereo_pair(0, H, W, 3)
    write_image(d / "left.png", left)
    write_image(d / "right.png", right)
    (d / "s8.sbs").write_bytes(write_samples(encode_image(right, pattern=SamplingPattern("grid", 3, 3))))
    (d / "s16.sbs").write_bytes(write_samples(encode_image(right.astype(np.uint16) * 257,
                                                           pattern=SamplingPattern("grid", 3, 3))))
    (d / "sgray.sbs").write_bytes(write_samples(encode_image(right[:, :, 1],
                                                             pattern=SamplingPattern("grid", 3, 3))))
    write_image(d / "left16.png", left.astype(np.uint16) * 257)
    write_image(d / "gray.png", left[:, :, 1], channel_order="gray")
    write_image(d / "bigger.png", _texture(1, H + 2, W + 8, 3))
    import cv2
    cv2.imwrite(str(d / "rgba.png"), np.dstack([left[:, :, ::-1], np.full((H, W), 128, np.uint8)]))
    (d / "text.png").write_text("this is not an image\n")
    (d / "empty.png").write_bytes(b"")
    (d / "zero.png").write_bytes(_png_header_only(0, 0))
    (d / "bomb.png").write_bytes(_png_header_only(100000, 100000))
    nan = np.full((H, W), 1.5, np.float32)
    nan[3, 4] = np.nan
    tifffile.imwrite(d / "nan.tif", nan)
    # Damaged files whose C decoders print their own complaints on stderr.
    ok, png = cv2.imencode(".png", left)
    png = bytearray(png.tobytes())
    png[100] ^= 0xFF
    (d / "crc.png").write_bytes(bytes(png))                         # libpng: IDAT CRC error
    (d / "cut.png").write_bytes(bytes(png[:len(png) // 2]))         # OpenCV: incomplete buffer
    ok, tif = cv2.imencode(".tiff", left)
    (d / "cut.tif").write_bytes(tif.tobytes()[:len(tif) // 2])      # libtiff + tifffile warnings
    ok, jpg = cv2.imencode(".jpg", _texture(5, 60, 80, 3))
    jpg = bytearray(jpg.tobytes())
    jpg[len(jpg) // 2] ^= 0xFF
    jpg[len(jpg) // 2 + 7] ^= 0x55
    (d / "damaged.jpg").write_bytes(bytes(jpg))                     # libjpeg: decodes, complains
    return d


def _run_all(commands, timeout=120):
    """Run command lines concurrently; returns CompletedProcess objects in order."""
    def one(cmd):
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    with ThreadPoolExecutor(max_workers=4) as pool:
        return list(pool.map(one, commands))


def assert_one_line_error(proc, code, *fragments):
    assert proc.returncode == code, (proc.returncode, proc.stderr)
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, proc.stderr
    assert ": error: " in lines[0]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


BAD_IMAGES = [("text.png", "not an image"), ("empty.png", "empty file"), ("zero.png", "0x0"),
              ("bomb.png", "100000x100000"), ("nan.tif", "NaN"), ("crc.png", "not an image"),
              ("cut.png", "not an image"), ("cut.tif", "not an image")]


def test_bad_images_through_both_commands(image_cases):
    d = image_cases
    commands, expected = [], []
    for name, fragment in BAD_IMAGES:
        commands.append([SB_ENCODE, str(d / name), "-o", str(d / f"{name}.sbs")])
        expected.append((9, str(d / name), fragment))
        commands.append([SB_DECODE, str(d / name), str(d / "s8.sbs"), "--max-disp", "5",
                         "--disparity", str(d / f"{name}.pfm")])
        expected.append((9, str(d / name), fragment))
    mismatches = [("left16.png", "s8.sbs", "uint16"), ("left.png", "s16.sbs", "uint16"),
                  ("gray.png", "s8.sbs", "channel"), ("left.png", "sgray.sbs", "channel"),
                  ("bigger.png", "s8.sbs", "48x32")]
    for left, sbs, fragment in mismatches:
        commands.append([SB_DECODE, str(d / left), str(d / sbs), "--max-disp", "5",
                         "--disparity", str(d / f"{left}-{sbs}.pfm")])
        expected.append((10, str(d / left), fragment))
    for proc, (code, path, fragment) in zip(_run_all(commands), expected):
        assert_one_line_error(proc, code, path, fragment)
    assert not list(d.glob("*.pfm")) and not list(d.glob("*.png.sbs")) and not list(d.glob("*.tif.sbs"))


def test_damage_the_decoder_survived_is_one_warning_line(image_cases):
    d = image_cases
    proc = subprocess.run([SB_ENCODE, str(d / "damaged.jpg"), "-o", str(d / "damaged.sbs"), "--overwrite"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("sb-encode: ") and "reported damage" in lines[0], lines
    assert read_samples((d / "damaged.sbs").read_bytes()).width == 80


def test_alpha_channel_is_dropped_with_a_note(image_cases):
    d = image_cases
    enc, dec = _run_all([
        [SB_ENCODE, str(d / "rgba.png"), "-o", str(d / "rgba.sbs"), "-v", "--overwrite"],
        [SB_DECODE, str(d / "rgba.png"), str(d / "s8.sbs"), "--max-disp", "5", "-v", "--overwrite",
         "--max-memory", "1G", "--disparity", str(d / "rgba.pfm")]])
    for proc in (enc, dec):
        assert proc.returncode == 0, proc.stderr
        assert "dropping the alpha channel" in proc.stderr and "Traceback" not in proc.stderr
    assert read_samples((d / "rgba.sbs").read_bytes()).channels == 3


# --- options -------------------------------------------------------------------------------------

def test_bad_options_are_refused(image_cases):
    from click.testing import CliRunner

    from stereobudget.cli.decode import decode_command

    d = image_cases
    left, sbs, out = str(d / "left.png"), str(d / "s8.sbs"), str(d / "opt.pfm")
    decode = [left, sbs, "--disparity", out]
    # sb-decode option errors in-process (they need the inputs read and the decoder loaded).
    in_process = [
        (decode + ["--max-disp", "5", "--min-disp", "5"], 2, "must be greater than --min-disp"),
        (decode + ["--max-disp", "3", "--min-disp", "5"], 2, "must be greater than --min-disp"),
        (decode + ["--max-disp", str(W + 5), "--min-disp", "10"], 2, "does not fit"),
        (decode + ["--max-disp", "5", "--min-disp", str(-W)], 2, "does not fit"),
        (decode + ["--max-disp", "5", "--max-memory", "lots"], 2, "--max-memory"),
        ([left, sbs, "--max-disp", "5", "--preview", str(d / "p.png"), "--right", str(d / "p.png")],
         2, "name the same file"),
        ([left, sbs, "--max-disp", "5", "--disparity", left.replace(".png", ".pfm"), "--right", left,
          "--overwrite"], 12, "same file as the input"),
    ]
    before = {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}
    for args, code, fragment in in_process:
        result = CliRunner().invoke(decode_command, args, prog_name="sb-decode")
        assert result.exit_code == code, (args, result.output)
        lines = [line for line in result.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and fragment in lines[0] and lines[0].startswith("sb-decode: error: "), lines
    # The same kinds of refusal from real processes (usage errors included: one line too).
    real = [
        ([SB_DECODE] + decode + ["--max-disp", str(W)], 2, "does not fit an image 40 pixels wide"),
        ([SB_DECODE] + decode + ["--max-disp", "0"], 2, "--max-disp"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "o.sbs"), "--stride", "-3"], 2, "--stride"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "o.sbs"), "--stride", "0"], 2, "--stride"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "o.sbs"), "--stride-y", "0"], 2, "--stride-y"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "o.sbs"), "--stride", "3", "--offset", "3,0"], 2,
         "smaller than the stride"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "o.sbs"), "--stride", "3", "--offset", "0,7"], 2,
         "smaller than the stride"),
        ([SB_ENCODE, str(d / "right.png"), "-o", str(d / "right.png"), "--overwrite"], 12,
         "same file as the input"),
    ]
    for proc, (_, code, fragment) in zip(_run_all([c[0] for c in real]), real):
        assert_one_line_error(proc, code, fragment)
    after = {p.name: p.read_bytes() for p in d.iterdir() if p.is_file()}
    assert after == before            # no input overwritten, no output created


def test_same_file_through_a_symlink_is_refused(image_cases, tmp_path):
    d = image_cases
    link = tmp_path / "alias.png"
    link.symlink_to(d / "left.png")
    original = (d / "left.png").read_bytes()
    proc = subprocess.run([SB_DECODE, str(d / "left.png"), str(d / "s8.sbs"), "--max-disp", "5",
                           "--right", str(link), "--overwrite"], capture_output=True, text=True, timeout=120)
    assert_one_line_error(proc, 12, "same file as the input")
    assert (d / "left.png").read_bytes() == original


# --- memory ----------------------------------------------------------------------------------------

def test_estimate_counts_volumes_and_grids():
    v = 100 * 200 * 48 * 4
    pixels = 100 * 200
    full = estimate_decode_memory(100, 200, 48, "full")
    assert full >= 1.25 * v                  # uint8 census volume + the two uint16 sums of the semi-global paths
    assert 2 * v <= estimate_decode_memory(100, 200, 48, "downsample")
    assert full < estimate_decode_memory(100, 200, 48, "downsample")   # 1.25 V against 2 V
    sparse = estimate_decode_memory(100, 200, 48, "sparse", stride_x=5, stride_y=5)
    hybrid = estimate_decode_memory(100, 200, 48, "hybrid", stride_x=5, stride_y=5)
    assert hybrid >= sparse and hybrid >= 2 * v
    # Smaller strides mean finer bilateral grids: more memory.
    assert estimate_decode_memory(100, 200, 48, "sparse", stride_x=2, stride_y=2) > sparse
    # Linear in the number of disparities (up to the per-pixel and fixed terms).
    double = estimate_decode_memory(100, 200, 96, "full")
    assert abs((double - full) - (full - 192 * pixels - 16 * 2 ** 20)) < 0.01 * full
    # The volumes' rows are padded to whole vectors of 8 layers, and the estimate counts them.
    assert estimate_decode_memory(100, 200, 41, "full") == full
    assert estimate_decode_memory(100, 200, 49, "full") > full
    with pytest.raises(ValueError):
        estimate_decode_memory(100, 200, 50, "magic")


def test_parse_size_and_default_limit(monkeypatch):
    assert sbio.parse_size("8G") == 8 * 2 ** 30
    assert sbio.parse_size("500M") == 500 * 2 ** 20
    assert sbio.parse_size("1.5GiB") == int(1.5 * 2 ** 30)
    assert sbio.parse_size("64k") == 64 * 1024
    assert sbio.parse_size("123456") == 123456
    for bad in ("", "lots", "-1G", "0", "1Q", "nan", "inf"):
        with pytest.raises(ValueError):
            sbio.parse_size(bad)
    with pytest.raises(ValueError, match="must be a finite number, got '1e400G'"):   # not "must be positive"
        sbio.parse_size("1e400G")
    monkeypatch.delenv(sbio.MEMORY_LIMIT_ENV, raising=False)
    available = sbio.available_memory()
    assert available and available > 0
    assert abs(sbio.default_memory_limit() - 0.75 * sbio.available_memory()) < 0.05 * available
    monkeypatch.setenv(sbio.MEMORY_LIMIT_ENV, "2G")
    assert sbio.default_memory_limit() == 2 * 2 ** 30


def test_decode_refuses_before_allocating(monkeypatch):
    from stereobudget.decoding import decode

    height, width, max_disp = 480, 640, 64
    rng = np.random.default_rng(4)
    left = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    samples = encode_image(rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
                           pattern=SamplingPattern("grid", 4, 4))
    need = estimate_decode_memory(height, width, max_disp + 1, "hybrid", stride_x=4, stride_y=4)
    one_cost_volume = height * width * (max_disp + 1) * 4      # float32 (H, W, D)
    tracemalloc.start()
    try:
        with pytest.raises(MemoryLimitError) as info:
            decode(left, samples, max_disp=max_disp, max_memory=need - 1, tile_rows=0)  # not tiled: refused
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < one_cost_volume // 4, f"{peak} bytes allocated before the memory check refused"
    message = str(info.value)
    assert "needs about" in message and "allowed" in message and "--max-disp" in message
    monkeypatch.setenv(sbio.MEMORY_LIMIT_ENV, "1M")
    with pytest.raises(MemoryLimitError, match=sbio.MEMORY_LIMIT_ENV):
        decode(left, samples, max_disp=max_disp, tile_rows=0)


def test_max_memory_option_exit_11(image_cases):
    d = image_cases
    refused, env = _run_all([
        [SB_DECODE, str(d / "left.png"), str(d / "s8.sbs"), "--max-disp", "5", "--max-memory", "2M",
         "--disparity", str(d / "mem_no.pfm")],
        ["env", f"{sbio.MEMORY_LIMIT_ENV}=3M", SB_DECODE, str(d / "left.png"), str(d / "s8.sbs"),
         "--max-disp", "5", "--disparity", str(d / "mem_env.pfm")]])
    assert_one_line_error(refused, 11, str(d / "left.png"), "needs about", "2.0 MiB is allowed")
    assert_one_line_error(env, 11, sbio.MEMORY_LIMIT_ENV)
    assert not (d / "mem_no.pfm").exists() and not (d / "mem_env.pfm").exists()


_PEAK_CHILD = r"""
import json, sys
import numpy as np
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern
from stereobudget.decoding import decode
import inspect
h, w, nd, cases = json.loads(sys.argv[1])
whole = {"tile_rows": 0} if "tile_rows" in inspect.signature(decode).parameters else {}
rng = np.random.default_rng(0)
left = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)

def rss(field):
    return int([l for l in open("/proc/self/status") if l.startswith(field)][0].split()[1]) * 1024

peaks = []
for method, stride, kind in cases:
    # JIT warm-up on a frame past the two-thread walk's threshold (16384 pixels), so that no
    # kernel is compiled (LLVM's memory) during the measured decode on a cold cache.
    small = encode_image(left[:128, :160], pattern=SamplingPattern(kind, stride, stride))
    decode(left[:128, :160], small, max_disp=5, method=method, **whole)
    samples = encode_image(left, pattern=SamplingPattern(kind, stride, stride))
    open("/proc/self/clear_refs", "w").write("5")                      # reset the peak RSS
    rest = rss("VmRSS")
    decode(left, samples, max_disp=nd - 1, method=method, **whole)
    peaks.append(rss("VmHWM") - rest)
print(json.dumps(peaks))
"""


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux /proc peak-RSS reset")
def test_estimate_bounds_the_measured_peak():
    h, w, nd = 240, 320, 48
    cases = [("hybrid", 3, "jitter"), ("full", 1, "grid")]
    proc = subprocess.run([sys.executable, "-c", _PEAK_CHILD, json.dumps([h, w, nd, cases])],
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-2000:]
    for (method, stride, _), measured in zip(cases, json.loads(proc.stdout.strip().splitlines()[-1])):
        estimate = estimate_decode_memory(h, w, nd, method, stride_x=stride, stride_y=stride)
        assert measured <= estimate, (method, measured, estimate)
        # Conservative, not absurd (the fixed 16 MiB allowance dominates at this small size).
        assert estimate <= 2.0 * measured + 16 * 2 ** 20, (method, measured, estimate)


# --- atomic outputs under SIGINT / SIGTERM -------------------------------------------------------

def _temp_leftovers(folder: Path) -> list:
    return [p.name for p in folder.iterdir() if p.name.startswith(".") and p.name.endswith(".tmp")]


def _pfm_ok(path: Path, shape) -> bool:
    from stereobudget.io import read_disparity
    return read_disparity(str(path)).shape == shape


def _png_shape(path: Path):
    import cv2
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return None if img is None else img.shape


def _kill_at(cmd, delay: float, sig) -> subprocess.CompletedProcess:
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    if proc.poll() is None:
        proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def _check_killed(proc):
    # 130: our handler ran; -SIGTERM/-SIGINT: killed before main() installed it (interpreter
    # start-up, nothing was written yet); 0: finished before the signal.
    assert proc.returncode in (0, 130, -signal.SIGTERM, -signal.SIGINT, 1), (proc.returncode, proc.stderr)
    if proc.returncode == 130:
        assert "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.strip().splitlines()[-1].endswith("interrupted")


@pytest.fixture(scope="module")
def kill_inputs(tmp_path_factory):
    from stereobudget.io import write_image
    d = tmp_path_factory.mktemp("kill")
    h, w = 180, 240
    left, right = _stereo_pair(3, h, w, 3, disparity=8)
    write_image(d / "left.png", left)
    write_image(d / "right.png", right)
    big = _texture(4, 1200, 1600, 3)
    write_image(d / "big.png", big)
    (d / "s.sbs").write_bytes(write_samples(encode_image(right, pattern=SamplingPattern("grid", 3, 3))))
    return d, (h, w), big.shape


def test_sigint_sigterm_mid_decode_leave_old_or_complete_outputs(kill_inputs, tmp_path):
    d, (h, w), _ = kill_inputs
    from stereobudget.io import write_disparity, write_preview
    from stereobudget.io import write_image
    old_disp = np.full((h, w), 7.0, np.float32)
    runs = []
    rng = random.Random(1234)
    # A full run takes ~2-4 s here (start-up + JIT cache load + a ~0.3 s decode + writes).
    delays = [rng.uniform(0.0, 4.0) for _ in range(4)] + [0.05]
    for i, delay in enumerate(delays):
        out = tmp_path / f"run{i}"
        out.mkdir()
        write_disparity(out / "d.pfm", old_disp)
        write_preview(out / "p.png", old_disp, min_disp=0, max_disp=24)
        write_image(out / "r.png", np.zeros((h, w, 3), np.uint8))
        olds = {name: (out / name).read_bytes() for name in ("d.pfm", "p.png", "r.png")}
        cmd = [SB_DECODE, str(d / "left.png"), str(d / "s.sbs"), "--max-disp", "24", "--overwrite",
               "--disparity", str(out / "d.pfm"), "--preview", str(out / "p.png"), "--right", str(out / "r.png")]
        runs.append((out, olds, cmd, delay, signal.SIGINT if i % 2 else signal.SIGTERM))
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda r: _kill_at(r[2], r[3], r[4]), runs))
    interrupted = 0
    for (out, olds, _, _, _), proc in zip(runs, results):
        _check_killed(proc)
        interrupted += proc.returncode != 0
        assert _temp_leftovers(out) == []
        for name, old in olds.items():
            now = (out / name).read_bytes()
            if now == old:
                continue
            if name == "d.pfm":
                assert _pfm_ok(out / name, (h, w))
            elif name == "p.png":              # the map, with its colour bar below
                shape = _png_shape(out / name)
                assert shape is not None and shape[0] > h and shape[1:] == (w, 3)
            else:
                assert _png_shape(out / name) == (h, w, 3)
        if proc.returncode == 0:
            assert all((out / n).read_bytes() != o for n, o in olds.items())
    assert interrupted >= 1


def test_console_script_exit_keeps_status_and_flushes_logging(image_cases):
    # The fast exit still runs the exit handlers and flushes: the -v summary line arrives,
    # and error statuses are unchanged.
    d = image_cases
    ok = subprocess.run([SB_DECODE, str(d / "left.png"), str(d / "s8.sbs"), "--max-disp", "5", "-v",
                         "--disparity", str(d / "fast_exit.pfm")], capture_output=True, text=True)
    assert ok.returncode == 0 and "fast_exit.pfm" in ok.stderr and (d / "fast_exit.pfm").exists()
    again = subprocess.run([SB_DECODE, str(d / "left.png"), str(d / "s8.sbs"), "--max-disp", "5",
                            "--disparity", str(d / "fast_exit.pfm")], capture_output=True, text=True)
    assert again.returncode == 12 and again.stderr.count("\n") == 1


def test_sigint_sigterm_mid_encode_leave_old_or_complete_outputs(kill_inputs, tmp_path):
    d, _, big_shape = kill_inputs
    old = write_samples(encode_image(np.zeros((8, 8), np.uint8), pattern=SamplingPattern("grid", 2, 2)))
    rng = random.Random(99)
    runs = []
    for i in range(5):
        out = tmp_path / f"enc{i}"
        out.mkdir()
        (out / "s.sbs").write_bytes(old)
        cmd = [SB_ENCODE, str(d / "big.png"), "-o", str(out / "s.sbs"), "--stride", "1", "--overwrite"]
        runs.append((out, cmd, rng.uniform(0.0, 1.5), signal.SIGINT if i % 2 else signal.SIGTERM))
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(lambda r: _kill_at(r[1], r[2], r[3]), runs))
    for (out, _, _, _), proc in zip(runs, results):
        _check_killed(proc)
        assert _temp_leftovers(out) == []
        data = (out / "s.sbs").read_bytes()
        if data != old:
            samples = read_samples(data)
            assert (samples.height, samples.width) == big_shape[:2]


# --- inputs that would exhaust memory or hang --------------------------------------------------

def test_oversized_input_files_are_refused_before_reading(tmp_path, image_cases):
    huge_image, huge_sbs = tmp_path / "huge.png", tmp_path / "huge.sbs"
    for path in (huge_image, huge_sbs):
        with open(path, "wb") as handle:          # sparse: 3 GiB on paper, nothing on disk
            handle.truncate(3 * 2 ** 30)
    enc, dec = _run_all([
        [SB_ENCODE, str(huge_image), "-o", str(tmp_path / "o.sbs")],
        [SB_DECODE, str(image_cases / "left.png"), str(huge_sbs), "--max-disp", "5",
         "--disparity", str(tmp_path / "d.pfm")]])
    assert_one_line_error(enc, 9, str(huge_image), "3.0 GiB", "at most 2.0 GiB")
    assert_one_line_error(dec, 4, str(huge_sbs), "3.0 GiB")


def test_endless_streams_are_cut_off():
    from stereobudget.io import read_input_bytes
    with pytest.raises(ImageReadError, match="goes on past"):
        read_input_bytes("/dev/zero", error=ImageReadError, max_bytes=3 * 2 ** 20)
    assert read_input_bytes("/dev/null", error=ImageReadError) == b""


def test_stdin_from_a_terminal_is_refused_instead_of_hanging(tmp_path):
    import pty
    leader, follower = pty.openpty()
    try:
        proc = subprocess.run([SB_ENCODE, "-", "-o", str(tmp_path / "o.sbs")], stdin=follower,
                              capture_output=True, text=True, timeout=60)
    finally:
        os.close(leader)
        os.close(follower)
    assert_one_line_error(proc, 9, "<stdin>", "terminal")

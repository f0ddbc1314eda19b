"""Mutation fuzzing of the ``.sbs`` reader and of ``sb-decode``.

Valid sample files of every pattern, channel layout and bit depth are mutated
(truncated, bit-flipped, spliced, header fields rewritten with a recomputed header CRC,
oversized header lengths, absurd dimensions, random bytes, payloads re-checksummed,
valid files of another image...) and every case is fed to

1. :func:`stereobudget.io.read_samples`,
2. the decode path of ``sb-decode`` in-process (:func:`stereobudget.pipeline.decode_file`,
   which reads, validates, decodes and writes the disparity map),
3. every ``--cli-every``-th case: ``sb-decode`` through click's ``CliRunner``,
4. every ``--subprocess-every``-th case: ``sb-decode`` as a real subprocess.

A case passes when it ends in a documented error (a
:class:`~stereobudget.errors.StereoBudgetError` subclass; for the CLI its exit code,
a single stderr line and no traceback) or decodes successfully; the reader and the
decoder must agree on the error class.  Anything else is a bug: the script prints the
case, saves it under ``--save-dir`` and exits 1.

    python scripts/fuzz_sample_file.py --seconds 300 --seed 1 --json fuzz.json
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import random
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import traceback
import zlib
from pathlib import Path

import numpy as np

from stereobudget.io import _samples as container
from stereobudget.io import MAGIC, read_samples, write_samples
from stereobudget.encoding import encode_image
from stereobudget.errors import StereoBudgetError
from stereobudget.sampling import SamplingPattern

#: Exit codes sb-decode may end with on a mutated sample file (docs/errors.md).
ALLOWED_EXIT_CODES = {0, 2, 4, 5, 6, 7, 8, 10, 11}

_FIELDS = container._FIELDS           # the 1.0 header layout after the magic
_NAMES = container._FIELD_NAMES
HEADER = container.HEADER_SIZE_V1_0

#: (name, pattern, stride, channels, dtype, channel order[, coding]) of the base files;
#: the coding is passed to write_samples (1.1 coded payloads).
BASES = (
    ("grid3_gray8", "grid", 3, 1, np.uint8, "gray"),
    ("grid4_rgb8", "grid", 4, 3, np.uint8, "rgb"),
    ("grid2_bgr8", "grid", 2, 3, np.uint8, "bgr"),
    ("jitter3_rgb16", "jitter", 3, 3, np.uint16, "rgb"),
    ("fps4_gray16", "fps", 4, 1, np.uint16, "gray"),
    ("adaptive3_rgb8", "adaptive_fps", 3, 3, np.uint8, "rgb"),
    ("downsample4_rgb8", "downsample", 4, 3, np.uint8, "rgb"),
    ("full_gray8", "grid", 1, 1, np.uint8, "gray"),
    ("grid3_rgb8_deflate", "grid", 3, 3, np.uint8, "rgb", {"codec": "deflate"}),
    ("grid2_bgr8_webpll", "grid", 2, 3, np.uint8, "bgr", {"codec": "webp_lossless"}),
    ("grid3_rgb8_webp", "grid", 3, 3, np.uint8, "rgb", {"codec": "webp", "quality": 70}),
    ("grid2_gray16_jxlll", "grid", 2, 1, np.uint16, "gray", {"codec": "jxl_lossless"}),
    ("downsample3_rgb8_jxl", "downsample", 3, 3, np.uint8, "rgb", {"codec": "jxl"}),
    ("fps3_rgb8_bits5", "fps", 3, 3, np.uint8, "rgb", {"value_bits": 5}),
    ("grid2_rgb16_bits11", "grid", 2, 3, np.uint16, "rgb", {"value_bits": 11}),
)
WIDTH, HEIGHT, MAX_DISP = 40, 30, 6


def _texture(rng: np.random.Generator, height: int, width: int, channels: int, dtype) -> np.ndarray:
    """A smooth random texture (so the decoders see something matchable)."""
    coarse = rng.random((height // 4 + 2, width // 4 + 2, channels))
    ys = np.linspace(0, coarse.shape[0] - 1.001, height)
    xs = np.linspace(0, coarse.shape[1] - 1.001, width)
    y0, x0 = ys.astype(int), xs.astype(int)
    fy, fx = (ys - y0)[:, None, None], (xs - x0)[None, :, None]
    img = (coarse[y0][:, x0] * (1 - fy) * (1 - fx) + coarse[y0 + 1][:, x0] * fy * (1 - fx)
           + coarse[y0][:, x0 + 1] * (1 - fy) * fx + coarse[y0 + 1][:, x0 + 1] * fy * fx)
    top = np.iinfo(dtype).max
    img = np.clip(img * top, 0, top).astype(dtype)
    return img[:, :, 0] if channels == 1 else img


def make_corpus(workdir: Path, seed: int = 0) -> list[dict]:
    """Write the base left images and sample files; return their descriptions."""
    from stereobudget.io import write_image

    rng = np.random.default_rng(seed)
    corpus = []
    from stereobudget.io import have_jxl

    for name, kind, stride, channels, dtype, order, *coding in BASES:
        coding = coding[0] if coding else {}
        if str(coding.get("codec", "")).startswith("jxl") and not have_jxl():
            continue
        wide = _texture(rng, HEIGHT, WIDTH + 3, channels, dtype)
        left, right = wide[:, 3:], wide[:, :-3]          # constant disparity 3
        pattern = SamplingPattern(kind=kind, stride_x=stride, stride_y=stride, seed=7 if kind != "grid"
                                  and kind != "downsample" else 0)
        stored = right[:, :, ::-1] if order == "bgr" else right
        sbs = write_samples(encode_image(np.ascontiguousarray(stored), pattern=pattern,
                                         channel_order=order), **coding)
        left_path = workdir / f"{name}_left.png"
        write_image(left_path, left, channel_order="gray" if channels == 1 else "rgb", overwrite=True)
        corpus.append({"name": name, "sbs": sbs, "left": str(left_path)})
    return corpus


# --- header surgery ------------------------------------------------------------------------

def header_fields(data: bytes) -> dict:
    return dict(zip(_NAMES, _FIELDS.unpack_from(data, len(MAGIC))))


def with_fields(data: bytes, *, fix_crc: bool = True, **changes) -> bytes:
    """``data`` with 1.0 header fields replaced (values masked to the field width) and the CRC redone."""
    fields = header_fields(data)
    fields.update(changes)
    widths = dict(zip(_NAMES, ("B", "B", "H", "I", "I", "B", "B", "B", "B", "H", "H", "H", "H", "Q",
                               "16s", "Q", "Q", "I")))
    for key, value in fields.items():
        if widths[key] != "16s":
            fields[key] = int(value) & ((1 << (8 * struct.calcsize(widths[key]))) - 1)
    head = MAGIC + _FIELDS.pack(*(fields[k] for k in _NAMES))
    crc = struct.unpack_from("<I", data, HEADER - 4)[0]
    if fix_crc:
        crc = zlib.crc32(head) & 0xFFFFFFFF
    return head + struct.pack("<I", crc) + data[HEADER:]


def with_payload(data: bytes, payload: bytes) -> bytes:
    """A consistent file with another payload (length and both CRCs recomputed)."""
    return with_fields(data[:HEADER] + payload, payload_length=len(payload),
                       payload_crc32=zlib.crc32(payload) & 0xFFFFFFFF)


def longer_header(data: bytes, extra: int) -> bytes:
    """A valid format-1.1 file whose header carries ``extra`` unknown bytes (forward compatible)."""
    fields = header_fields(data)
    fields.update(version_minor=1, header_length=HEADER + extra)
    head = MAGIC + _FIELDS.pack(*(fields[k] for k in _NAMES)) + bytes(extra)
    return head + struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF) + data[HEADER:]


# --- mutations -----------------------------------------------------------------------------

def _flip_bits(rng, data, lo=0, hi=None):
    buf = bytearray(data)
    hi = len(buf) if hi is None else min(hi, len(buf))
    for _ in range(rng.randint(1, 8)):
        i = rng.randrange(lo, hi)
        buf[i] ^= 1 << rng.randrange(8)
    return bytes(buf)


def _absurd_dimension(rng):
    return rng.choice([0, 1, 2, 65535, 65536, 100000, 2 ** 31 - 1, 2 ** 32 - 1, 16385, 16384 * 2])


MUTATIONS = {}


def mutation(func):
    MUTATIONS[func.__name__] = func
    return func


@mutation
def unchanged(rng, base, other):
    return base


@mutation
def truncated(rng, base, other):
    return base[:rng.randrange(0, len(base))]


@mutation
def bit_flip_header(rng, base, other):
    return _flip_bits(rng, base, 0, HEADER)


@mutation
def bit_flip_payload(rng, base, other):
    return _flip_bits(rng, base, HEADER)


@mutation
def bit_flip_anywhere(rng, base, other):
    return _flip_bits(rng, base)


@mutation
def spliced(rng, base, other):
    return base[:rng.randrange(0, len(base) + 1)] + other[rng.randrange(0, len(other) + 1):]


@mutation
def header_of_other(rng, base, other):
    return other[:HEADER] + base[HEADER:]


@mutation
def oversized_header_length(rng, base, other):
    length = rng.choice([81, 84, 96, 200, 4096, 0xFFFF, 0, 4, 79])
    minor = rng.choice([0, 1, 7])
    return with_fields(base, fix_crc=rng.random() < 0.8, header_length=length, version_minor=minor)


@mutation
def valid_longer_header(rng, base, other):
    return longer_header(base, rng.choice([4, 16, 100]))


@mutation
def absurd_dimensions(rng, base, other):
    changes = {"width": _absurd_dimension(rng)} if rng.random() < 0.4 else {}
    if not changes or rng.random() < 0.5:
        changes["height"] = _absurd_dimension(rng)
    if rng.random() < 0.5:
        # Keep sample count / payload length consistent with the header's claim, so the
        # dimension check (not a count check) is what must refuse it.
        changes["sample_count"] = rng.choice([2 ** 40, 2 ** 63, 12345678901])
        changes["payload_length"] = changes["sample_count"] * header_fields(base)["channels"]
    return with_fields(base, **changes)


@mutation
def random_field(rng, base, other):
    name = rng.choice([n for n in _NAMES if n not in ("pattern_reserved",)])
    value = rng.choice([0, 1, 2, 3, 4, 5, 255, 256, 65535, 2 ** 32 - 1, 2 ** 63, rng.getrandbits(64)])
    return with_fields(base, fix_crc=rng.random() < 0.9, **{name: value})


@mutation
def coding_block(rng, base, other):
    """The 1.1 coding block (codec, value_bits, quality, values CRC) rewritten, header CRC fixed."""
    block = bytearray(base[40:56])
    for _ in range(rng.randint(1, 3)):
        where = rng.choice([0, 1, 2, 3, 4, 8])
        block[where] = rng.choice([0, 1, 2, 3, 4, 5, 6, 8, 9, 12, 16, 17, 90, 100, 101, 255, rng.getrandbits(8)])
    data = with_fields(base, version_minor=rng.choice([1, 1, 1, 0, 2]), fix_crc=False)
    head = bytearray(data[:HEADER - 4])
    head[40:56] = block
    return bytes(head) + struct.pack("<I", zlib.crc32(head) & 0xFFFFFFFF) + base[HEADER:]


@mutation
def valid_pattern_change(rng, base, other):
    """Another seed / stride with a consistent count: a valid file of a different pattern."""
    f = header_fields(base)
    kinds = list(container.PATTERN_CODES)
    kind = rng.choice(kinds)
    stride = rng.randint(1, 9)
    pattern = SamplingPattern(kind=kind, stride_x=stride, stride_y=rng.randint(1, 9),
                              seed=0 if kind in ("grid", "downsample") else rng.getrandbits(64))
    n = container.sample_count(pattern, f["height"], f["width"])
    payload = bytes(rng.getrandbits(8) for _ in range(n * f["channels"] * f["dtype_code"]))
    data = with_fields(base[:HEADER], pattern_code=container.PATTERN_CODES[kind],
                       stride_x=pattern.stride_x, stride_y=pattern.stride_y, seed=pattern.seed,
                       sample_count=n)
    return with_payload(data, payload)


@mutation
def payload_recomputed_crc(rng, base, other):
    payload = _flip_bits(rng, base[HEADER:]) if len(base) > HEADER else b""
    return with_payload(base, payload)


@mutation
def random_bytes(rng, base, other):
    return bytes(rng.getrandbits(8) for _ in range(rng.choice([0, 1, 7, 8, 79, 80, 81, 500])))


@mutation
def magic_then_random(rng, base, other):
    return MAGIC + bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 300)))


@mutation
def text_mode_damage(rng, base, other):
    return rng.choice([base.replace(b"\r\n", b"\n"), base.replace(b"\n", b"\r\n"),
                       bytes([base[0] & 0x7F]) + base[1:],
                       base.decode("latin-1").encode("utf-8"),
                       base.decode("utf-8", "replace").encode("utf-8")])


@mutation
def inserted_or_deleted(rng, base, other):
    i = rng.randrange(0, len(base) + 1)
    if rng.random() < 0.5:
        return base[:i] + bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 16))) + base[i:]
    return base[:i] + base[i + rng.randint(1, 16):]


@mutation
def appended(rng, base, other):
    return base + bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 64)))


@mutation
def mismatched_valid(rng, base, other):
    """A valid file of another image (different layout, bit depth, or size)."""
    return other


# --- checks --------------------------------------------------------------------------------

class Bug(Exception):
    """A case ended in something other than a documented outcome."""


def reader_outcome(data: bytes) -> str:
    """``ok`` or the error class name; raises :class:`Bug` for anything undocumented."""
    try:
        read_samples(data, source="fuzz.sbs")
    except StereoBudgetError as exc:
        if "\n" in str(exc):
            raise Bug(f"multi-line message from read_samples: {exc!r}") from None
        return type(exc).__name__
    except Exception as exc:   # noqa: BLE001 -- that is the point of the fuzzer
        raise Bug(f"read_samples raised {type(exc).__name__}: {exc}\n{traceback.format_exc()}") from None
    return "ok"


def decode_outcome(sbs_path: Path, left: str, out: Path) -> tuple[str, object]:
    """Run sb-decode's per-pair path in-process; ``(outcome, exception or None)``."""
    from stereobudget.pipeline import DecodeJob, decode_file

    job = DecodeJob(left=left, samples=str(sbs_path), disparity=str(out), max_disp=MAX_DISP,
                    overwrite=True)
    try:
        decode_file(job)
    except StereoBudgetError as exc:
        return type(exc).__name__, exc
    except Exception as exc:   # noqa: BLE001
        raise Bug(f"decode_file raised {type(exc).__name__}: {exc}\n{traceback.format_exc()}") from None
    from stereobudget.io import read_disparity
    disp = read_disparity(str(out))
    if disp.shape != (HEIGHT, WIDTH):
        raise Bug(f"decoded disparity has shape {disp.shape}")
    return "ok", None


def _check_cli_result(code: int, stderr: str, what: str, expected_code: int | None) -> None:
    if code not in ALLOWED_EXIT_CODES:
        raise Bug(f"{what}: exit code {code} not documented; stderr: {stderr[-2000:]}")
    if "Traceback" in stderr:
        raise Bug(f"{what}: traceback on stderr:\n{stderr[-2000:]}")
    lines = [line for line in stderr.splitlines() if line.strip()]
    if code != 0 and len(lines) != 1:
        raise Bug(f"{what}: expected one stderr line, got {len(lines)}: {stderr[-2000:]}")
    if expected_code is not None and code != expected_code:
        raise Bug(f"{what}: exit code {code}, the library path gave {expected_code}; stderr: {stderr}")


def cli_runner_outcome(sbs_path: Path, left: str, out: Path, expected_code: int | None) -> int:
    from click.testing import CliRunner

    from stereobudget.cli.decode import decode_command

    runner = CliRunner()
    result = runner.invoke(decode_command, [left, str(sbs_path), "--max-disp", str(MAX_DISP),
                                            "--disparity", str(out), "--overwrite"], prog_name="sb-decode")
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise Bug(f"CliRunner: {type(result.exception).__name__}: {result.exception}\n"
                  + "".join(traceback.format_exception(*result.exc_info)))
    stderr = result.stderr if hasattr(result, "stderr") else result.output
    _check_cli_result(result.exit_code, stderr, "sb-decode (CliRunner)", expected_code)
    return result.exit_code


def _sb_decode_command() -> list[str]:
    exe = shutil.which("sb-decode", path=os.path.dirname(sys.executable)) or shutil.which("sb-decode")
    return [exe] if exe else [sys.executable, "-m", "stereobudget.cli.decode"]


def subprocess_outcome(sbs_path: Path, left: str, out: Path, expected_code: int | None) -> int:
    proc = subprocess.run(_sb_decode_command() + [left, str(sbs_path), "--max-disp", str(MAX_DISP),
                                                  "--disparity", str(out), "--overwrite"],
                          capture_output=True, text=True, timeout=120)
    _check_cli_result(proc.returncode, proc.stderr, "sb-decode (subprocess)", expected_code)
    return proc.returncode


def run(*, seconds: float, seed: int, cli_every: int, subprocess_every: int, save_dir: Path | None,
        max_cases: int | None = None, threads: int | None = 1, log=print) -> dict:
    """Fuzz for ``seconds`` (or ``max_cases``); return the counts.  Raises :class:`Bug`."""
    if threads:
        # Tiny images: numba's thread start-up costs more than the work.
        import numba
        numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))
    rng = random.Random(seed)
    workdir = Path(tempfile.mkdtemp(prefix="sb-fuzz-"))
    counts = {"cases": 0, "mutations": collections.Counter(), "reader": collections.Counter(),
              "decode": collections.Counter(), "cli_runner": collections.Counter(),
              "subprocess": collections.Counter()}
    exit_codes = {}
    try:
        corpus = make_corpus(workdir, seed)
        names = sorted(MUTATIONS)
        sbs_path, out = workdir / "case.sbs", workdir / "out.pfm"
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and (max_cases is None or counts["cases"] < max_cases):
            base, other = rng.choice(corpus), rng.choice(corpus)
            kind = rng.choice(names)
            data = MUTATIONS[kind](rng, base["sbs"], other["sbs"])
            case = counts["cases"]
            counts["cases"] += 1
            counts["mutations"][kind] += 1
            try:
                reader = reader_outcome(data)
                sbs_path.write_bytes(data)
                decoded, exc = decode_outcome(sbs_path, base["left"], out)
                if reader != "ok" and decoded != reader:
                    raise Bug(f"reader says {reader} but the decode path says {decoded}")
                if reader == "ok" and decoded not in ("ok", "MismatchError", "OptionError"):
                    raise Bug(f"valid file, but the decode path says {decoded}: {exc}")
                if kind in ("unchanged", "valid_longer_header") and decoded != "ok":
                    raise Bug(f"{kind}: a valid matching file failed to decode: {exc}")
                counts["reader"][reader] += 1
                counts["decode"][decoded] += 1
                code = getattr(exc, "exit_code", 0)
                exit_codes.setdefault(decoded, code)
                if cli_every and case % cli_every == 0:
                    counts["cli_runner"][cli_runner_outcome(sbs_path, base["left"], out, code)] += 1
                if subprocess_every and case % subprocess_every == 0:
                    counts["subprocess"][subprocess_outcome(sbs_path, base["left"], out, code)] += 1
            except Bug as bug:
                if save_dir is not None:
                    save_dir.mkdir(parents=True, exist_ok=True)
                    (save_dir / f"case{case}_{kind}_{base['name']}.sbs").write_bytes(data)
                log(f"BUG in case {case} ({kind} of {base['name']}): {bug}")
                raise
            if case % 500 == 0:
                log(f"{case} cases, {dict(counts['decode'])}")
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    result = {key: (dict(value) if isinstance(value, collections.Counter) else value)
              for key, value in counts.items()}
    result["exit_codes"] = exit_codes
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0, help="How long to run.")
    parser.add_argument("--max-cases", type=int, default=None, help="Stop after this many cases.")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cli-every", type=int, default=20, help="Every N-th case also via CliRunner.")
    parser.add_argument("--subprocess-every", type=int, default=150,
                        help="Every N-th case also as a real sb-decode process (0 = never).")
    parser.add_argument("--save-dir", type=Path, default=Path("fuzz-failures"),
                        help="Where a failing case is saved.")
    parser.add_argument("--threads", type=int, default=1, help="numba threads in this process.")
    parser.add_argument("--json", help="Write the counts to this file.")
    args = parser.parse_args(argv)
    start = time.monotonic()
    try:
        result = run(seconds=args.seconds, seed=args.seed, cli_every=args.cli_every,
                     subprocess_every=args.subprocess_every, save_dir=args.save_dir,
                     max_cases=args.max_cases, threads=args.threads, log=lambda msg: print(msg, file=sys.stderr, flush=True))
    except Bug:
        return 1
    result["seconds"] = round(time.monotonic() - start, 1)
    text = json.dumps(result, indent=1, sort_keys=True)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Frame streams: concatenated .sbs frames and raw frames read one at a time, errors naming the frame."""

from __future__ import annotations

import numpy as np
import pytest

from stereobudget.errors import CorruptHeaderError, ImageReadError, NotASampleFileError, TruncatedFileError
from stereobudget.io import holds_several_frames, raw_frames, read_samples, sample_frames, write_samples
from stereobudget.encoding import encode_image
from stereobudget.sampling import SamplingPattern


def _frames(count, *, shape=(37, 45, 3), stride=4):
    rng = np.random.default_rng(7)
    return [write_samples(encode_image(rng.integers(0, 256, shape, dtype=np.uint8),
                                       pattern=SamplingPattern("grid", stride, stride)))
            for _ in range(count)]


def test_a_stream_is_its_frames_back_to_back(tmp_path):
    frames = _frames(3)
    path = tmp_path / "s.sbs"
    path.write_bytes(b"".join(frames))
    assert list(sample_frames(path)) == frames
    assert [read_samples(f).values.shape for f in sample_frames(path)] == [(120, 3)] * 3
    assert holds_several_frames(path)
    (tmp_path / "one.sbs").write_bytes(frames[0])
    assert list(sample_frames(tmp_path / "one.sbs")) == frames[:1]
    assert not holds_several_frames(tmp_path / "one.sbs") and not holds_several_frames("-")


@pytest.mark.parametrize("cut, error, fragment", [
    (0, TruncatedFileError, "empty file"),
    (-5, TruncatedFileError, "frame 2 is truncated: payload has"),
    ("inside header", TruncatedFileError, "frame 2: file ends inside the header"),
])
def test_a_cut_stream_names_the_frame(tmp_path, cut, error, fragment):
    frames = _frames(3)
    data = b"".join(frames)
    if cut == 0:
        data = b""
    elif cut == "inside header":
        data = data[:len(frames[0]) * 2 + 30]
    else:
        data = data[:cut]
    path = tmp_path / "cut.sbs"
    path.write_bytes(data)
    read = []
    with pytest.raises(error, match=fragment):
        for frame in sample_frames(path):
            read.append(frame)
    assert read == frames[:len(read)] and len(read) == (0 if cut == 0 else 2)


def test_damage_after_the_first_frame_is_reported_with_its_index(tmp_path):
    frames = _frames(3)
    damaged = bytearray(frames[1])
    damaged[20] ^= 0xFF                  # a header field: the header checksum fails
    path = tmp_path / "d.sbs"
    path.write_bytes(frames[0] + bytes(damaged) + frames[2])
    with pytest.raises(CorruptHeaderError, match="frame 1: header checksum mismatch"):
        list(sample_frames(path))
    path.write_bytes(frames[0] + b"garbage that is no frame at all, long enough for a header" * 2)
    with pytest.raises(NotASampleFileError, match="frame 1: not a stereobudget sample file"):
        list(sample_frames(path))


def test_a_single_file_with_a_second_frame_points_to_streams(tmp_path):
    frames = _frames(2)
    from stereobudget.errors import CorruptPayloadError
    with pytest.raises(CorruptPayloadError, match=r"another \.sbs frame follows .* \{index\}"):
        read_samples(b"".join(frames))


def test_raw_frames_one_at_a_time(tmp_path):
    frame_bytes = 6 * 4 * 3
    data = bytes(range(256)) * 2
    path = tmp_path / "f.raw"
    path.write_bytes(data[:3 * frame_bytes])
    frames = list(raw_frames(path, width=6, height=4, pix_fmt="rgb24"))
    assert frames == [data[i * frame_bytes:(i + 1) * frame_bytes] for i in range(3)]
    path.write_bytes(data[:3 * frame_bytes - 1])
    with pytest.raises(ImageReadError, match="frame 2 is cut short at 71 bytes"):
        list(raw_frames(path, width=6, height=4, pix_fmt="rgb24"))
    path.write_bytes(b"")
    with pytest.raises(ImageReadError, match="got 0 \\(less than one frame\\)"):
        list(raw_frames(path, width=6, height=4, pix_fmt="rgb24"))
    with pytest.raises(ImageReadError, match="unknown raw pixel format"):
        list(raw_frames(path, width=6, height=4, pix_fmt="yuv"))

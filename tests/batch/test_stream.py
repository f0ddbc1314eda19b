"""Streams in one process: encode_stream and decode_stream give what one file at a time gives."""

from __future__ import annotations

import numpy as np
import pytest

from stereobudget.batch import decode_stream, encode_stream, expand_template
from stereobudget.pipeline import DecodeJob, decode_file
from stereobudget.errors import MismatchError, OptionError, TruncatedFileError
from stereobudget.io import read_disparity, sample_frames
from stereobudget.encoding import encode_file
from stereobudget.sampling import SamplingPattern

GRID = SamplingPattern("grid", 5, 5)


@pytest.fixture(scope="module")
def frames(camera_frames):
    return camera_frames


def test_template_index_takes_an_integer_format():
    assert expand_template("D/{index:05d}_{stem}.pfm", "L/a.png", index=7) == "D/00007_a.pfm"
    assert expand_template("D/{index}.pfm", "x", index=12) == "D/12.pfm"
    with pytest.raises(OptionError, match="not an integer format"):
        expand_template("{index:q}", "x", index=1)
    with pytest.raises(OptionError, match="numbers the frames of a stream"):
        expand_template("{index}", "x")


def test_a_raw_stream_encodes_to_the_frames_one_file_at_a_time_gives(frames):
    singles = []
    for index in range(3):
        out = frames / f"single{index}.sbs"
        encode_file(frames / f"r{index}.png", out, pattern=GRID, overwrite=True)
        singles.append(out.read_bytes())
    stream = frames / "stream.sbs"
    items = list(encode_stream([str(frames / "rights.raw")], str(stream), pattern=GRID, raw_size=(96, 64),
                               pix_fmt="rgb24", overwrite=True))
    assert [item["frame"] for item in items] == [0, 1, 2]
    assert list(sample_frames(stream)) == singles
    per_frame = list(encode_stream([str(frames / "rights.raw")], str(frames / "S" / "{index:02d}.sbs"),
                                   pattern=GRID, raw_size=(96, 64), pix_fmt="rgb24", overwrite=True))
    assert [(frames / "S" / f"{i:02d}.sbs").read_bytes() for i in range(3)] == singles
    assert per_frame[2]["output"] == str(frames / "S" / "02.sbs")
    images = list(encode_stream([str(frames / f"r{i}.png") for i in range(3)], str(frames / "images.sbs"),
                                pattern=GRID, overwrite=True))
    assert len(images) == 3 and (frames / "images.sbs").read_bytes() == stream.read_bytes()


def test_a_failing_stream_leaves_no_half_written_stream_file(frames):
    cut = frames / "cut.raw"
    cut.write_bytes((frames / "rights.raw").read_bytes()[:-10])
    with pytest.raises(Exception, match="frame 2 is cut short"):
        list(encode_stream([str(cut)], str(frames / "cut.sbs"), pattern=GRID, raw_size=(96, 64),
                           pix_fmt="rgb24"))
    assert not (frames / "cut.sbs").exists() and not list(frames.glob(".cut.sbs*"))


def test_decode_stream_equals_decoding_each_frame_alone(frames):
    stream = frames / "dstream.sbs"
    list(encode_stream([str(frames / "rights.raw")], str(stream), pattern=GRID, raw_size=(96, 64),
                       pix_fmt="rgb24", overwrite=True))
    summaries = list(decode_stream(str(frames / "L" / "{index}.png"), str(stream), max_disp=16,
                                   disparity=str(frames / "D" / "{index}.pfm"),
                                   right=str(frames / "R" / "{index}.png"), overwrite=True))
    assert [s["frame"] for s in summaries] == [0, 1, 2]
    assert summaries[1]["samples"].endswith("frame 1")
    for index in range(3):
        single = frames / f"single{index}.sbs"
        encode_file(frames / f"r{index}.png", single, pattern=GRID, overwrite=True)
        decode_file(DecodeJob(left=str(frames / "L" / f"{index}.png"), samples=str(single), max_disp=16,
                              disparity=str(frames / f"alone{index}.pfm"), right=str(frames / f"alone{index}.png"),
                              overwrite=True))
        np.testing.assert_array_equal(read_disparity(frames / "D" / f"{index}.pfm"),
                                      read_disparity(frames / f"alone{index}.pfm"))
        assert (frames / "R" / f"{index}.png").read_bytes() == (frames / f"alone{index}.png").read_bytes()


def test_stream_errors_name_the_frame_and_keep_the_frames_before(frames, tmp_path):
    stream = frames / "estream.sbs"
    list(encode_stream([str(frames / "rights.raw")], str(stream), pattern=GRID, raw_size=(96, 64),
                       pix_fmt="rgb24", overwrite=True))
    # A plain output name holds one frame: the second is refused, the first stays.
    with pytest.raises(OptionError, match="frame 1 would write --disparity .*one.pfm again \\(frame 0 wrote it\\)"):
        list(decode_stream(str(frames / "L" / "0.png"), str(stream), max_disp=16,
                           disparity=str(tmp_path / "one.pfm")))
    assert (tmp_path / "one.pfm").exists()
    # Fewer left images than frames.
    lefts = tmp_path / "lefts"
    lefts.mkdir()
    for index in range(2):
        (lefts / f"{index}.png").write_bytes((frames / "L" / f"{index}.png").read_bytes())
    with pytest.raises(MismatchError, match="more frames than the 2 left images"):
        list(decode_stream(str(lefts), str(stream), max_disp=16, disparity=str(tmp_path / "a" / "{index}.pfm")))
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["0.pfm", "1.pfm"]
    # A cut stream: the whole frames are decoded, then the error.
    cut = tmp_path / "cut.sbs"
    cut.write_bytes(stream.read_bytes()[:-7])
    with pytest.raises(TruncatedFileError, match="frame 2 is truncated"):
        list(decode_stream(str(frames / "L" / "{index}.png"), str(cut), max_disp=16,
                           disparity=str(tmp_path / "b" / "{index}.pfm")))
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["0.pfm", "1.pfm"]


def test_a_budget_stream_writes_what_one_budget_file_at_a_time_writes(frames):
    # Each frame's search starts at the previous frame's choice; the files must not change.
    coding = {"codec": "raw", "size": 900}
    singles = []
    for index in range(3):
        out = frames / f"budget{index}.sbs"
        encode_file(frames / f"r{index}.png", out, pattern=SamplingPattern("grid", 1, 1), overwrite=True, **coding)
        singles.append(out.read_bytes())
    stream = frames / "budget.sbs"
    items = list(encode_stream([str(frames / "rights.raw")], str(stream), pattern=SamplingPattern("grid", 1, 1),
                               raw_size=(96, 64), pix_fmt="rgb24", overwrite=True, coding=coding))
    assert list(sample_frames(stream)) == singles
    assert all(item["file_size"] <= 900 for item in items)


def test_a_frame_of_another_size_ends_a_temporal_stream_naming_the_frame(frames, tmp_path):
    import cv2

    from stereobudget.scenes import make_scene

    small = make_scene("slanted", height=40, width=64, max_disp=8, seed=5)
    (tmp_path / "L").mkdir()
    (tmp_path / "L" / "0.png").write_bytes((frames / "L" / "0.png").read_bytes())
    assert cv2.imwrite(str(tmp_path / "L" / "1.png"), np.ascontiguousarray(small.left[:, :, ::-1]))
    assert cv2.imwrite(str(tmp_path / "r1.png"), np.ascontiguousarray(small.right[:, :, ::-1]))
    encode_file(frames / "r0.png", tmp_path / "s0.sbs", pattern=GRID)
    encode_file(tmp_path / "r1.png", tmp_path / "s1.sbs", pattern=GRID)
    stream = tmp_path / "sizes.sbs"
    stream.write_bytes((tmp_path / "s0.sbs").read_bytes() + (tmp_path / "s1.sbs").read_bytes())
    with pytest.raises(MismatchError, match="frame 1 is 64x40, the stream's frames are 96x64 .*sizes.sbs.*frame 1"):
        list(decode_stream(str(tmp_path / "L" / "{index}.png"), str(stream), max_disp=16,
                           disparity=str(tmp_path / "D" / "{index}.pfm")))
    assert sorted(p.name for p in (tmp_path / "D").iterdir()) == ["0.pfm"]
    # Frames decoded each on its own may change size.
    items = list(decode_stream(str(tmp_path / "L" / "{index}.png"), str(stream), max_disp=16, temporal=False,
                               disparity=str(tmp_path / "E" / "{index}.pfm")))
    assert [item["width"] for item in items] == [96, 64]


def test_left_images_written_while_the_stream_runs_are_read_as_they_are_when_their_frame_comes(frames, tmp_path):
    """The next frame's left image is read while a frame decodes.  One that is not there yet,
    and one that is rewritten after that read, are both taken as they are at their frame."""
    import os
    import threading

    stream = frames / "lstream.sbs"
    list(encode_stream([str(frames / "rights.raw")], str(stream), pattern=GRID, raw_size=(96, 64),
                       pix_fmt="rgb24", overwrite=True))
    lefts = tmp_path / "L"
    lefts.mkdir()
    (lefts / "0.png").write_bytes((frames / "L" / "0.png").read_bytes())
    (lefts / "1.png").write_bytes((frames / "L" / "0.png").read_bytes())    # the wrong image, for now
    frames_seen = []
    threads_before = threading.active_count()
    for summary in decode_stream(str(lefts / "{index}.png"), str(stream), max_disp=16,
                                 disparity=str(tmp_path / "D" / "{index}.pfm")):
        frames_seen.append(summary["frame"])
        if summary["frame"] == 0:
            # Frame 1's image was read ahead while frame 0 decoded; frame 2's does not exist yet.
            (lefts / "1.png").write_bytes((frames / "L" / "1.png").read_bytes())
            stamp = os.stat(lefts / "1.png")
            os.utime(lefts / "1.png", ns=(stamp.st_atime_ns, stamp.st_mtime_ns + 10 ** 9))
            (lefts / "2.png").write_bytes((frames / "L" / "2.png").read_bytes())
    assert frames_seen == [0, 1, 2]
    assert threading.active_count() == threads_before      # the reading thread is gone
    for index in range(3):
        alone = tmp_path / f"alone{index}.sbs"
        encode_file(frames / f"r{index}.png", alone, pattern=GRID, overwrite=True)
        decode_file(DecodeJob(left=str(frames / "L" / f"{index}.png"), samples=str(alone), max_disp=16,
                              disparity=str(tmp_path / f"alone{index}.pfm")))
        np.testing.assert_array_equal(read_disparity(tmp_path / "D" / f"{index}.pfm"),
                                      read_disparity(tmp_path / f"alone{index}.pfm"))

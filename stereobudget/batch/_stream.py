"""Frame streams in one process: a camera's raw frames to ``.sbs`` frames, ``.sbs`` frames to disparity.

A camera sends frames continuously; starting a process per frame would spend most of
the time on imports (and, on the host, on loading the compiled kernels).  Here every
frame of a stream goes through the same process, in order, as it arrives:

* :func:`encode_stream` -- ``sb-encode`` of a raw stream (``--raw WxH`` input holding
  any number of frames) or of several images, to standard output (frames one after
  another, flushed as each is done), to one stream file (written atomically once the
  stream ends), or to one file per frame through a template with ``{index}``.
* :func:`decode_stream` -- ``sb-decode`` of a stream of concatenated ``.sbs`` frames (a
  file or standard input) against one left image, a folder or glob of left images (in
  name order, one per frame) or a ``{index}`` template; outputs go through ``{index}``
  templates, or to standard output as one image after another (``--disparity -``: PFM
  frames, or 16-bit PNG frames with ``--format png``).

Frames are numbered from 0.  An error ends the stream with the error's own exit code and
names the frame; the frames before it are complete, every file written whole.
"""

from __future__ import annotations

import logging
import os
import time
from typing import Iterable, Iterator

from ..errors import MismatchError, OptionError
from ..io._atomic import STDIO, atomic_write, display_name, write_output_bytes
from ..io._stream import frame_label, raw_frames, sample_frames
from ._inputs import IMAGE_EXTENSIONS, expand_inputs, expand_template, uses_field
from ..pipeline._jobs import DecodeJob, decode_arrays
from ..pipeline._outputs import check_job_outputs, prepare_outputs

log = logging.getLogger("stereobudget")


def _frame_output(template: str | None, *, source: str, index: int, option: str) -> str | None:
    """``template`` for frame ``index`` (``-`` and names without fields stay as they are)."""
    if template is None or template == STDIO:
        return template
    return expand_template(template, source, option=option, index=index)


def _one_file_per_frame(template: str | None, option: str) -> bool:
    return template is not None and template != STDIO and uses_field(template, "index", option)


# =====================================================================================
# Camera side
# =====================================================================================

def _encode_inputs(sources: list[str], *, raw_size, pix_fmt) -> Iterator[tuple[str, object]]:
    """(name, frame) of every frame: all frames of one raw stream, or one image per source."""
    if raw_size is not None:
        if len(sources) != 1:
            raise OptionError("a raw stream is one input (a file or '-'); got "
                              f"{len(sources)}")
        name = display_name(sources[0])
        for index, frame in enumerate(raw_frames(sources[0], width=raw_size[0], height=raw_size[1],
                                                 pix_fmt=pix_fmt)):
            yield frame_label(name, index) if index else name, frame
        return
    from ..io import _images as imageio
    for source in sources:
        name = display_name(source)
        yield name, imageio.read_image(source, name=name)


def encode_stream(sources: Iterable[str], output: str, *, pattern, raw_size: tuple[int, int] | None = None,
                  pix_fmt: str | None = None, overwrite: bool = False,
                  coding: dict | None = None) -> Iterator[dict]:
    """Encode a stream of right frames into ``.sbs`` frames, one at a time; yield a report per frame.

    Parameters
    ----------
    sources : list of str
        With ``raw_size``: one raw stream (a file or ``-``) of any number of frames.
        Without: images, one frame each, in the order given.
    output : str
        ``-``: the frames one after another on standard output, each flushed when done;
        a template using ``{index}`` (e.g. ``'S/{index:05d}.sbs'``): one file per frame;
        any other name: one stream file holding every frame, written atomically when the
        stream ends.
    pattern, raw_size, pix_fmt, coding
        As :func:`stereobudget.encoding.encode_file` (``coding``: its keyword arguments).
    overwrite : bool
        Replace existing outputs.

    Yields
    ------
    dict
        The frame's :class:`~stereobudget.encoding.EncodeReport` fields, ``frame`` (its index)
        and ``output``.
    """
    from ..encoding import encode_frame

    sources = list(sources)
    per_frame = _one_file_per_frame(output, "-o")
    first_source = display_name(sources[0]) if sources else "-"

    def frames():
        previous = None   # a budget search starts at the previous frame's choice
        for index, (name, frame) in enumerate(_encode_inputs(sources, raw_size=raw_size, pix_fmt=pix_fmt)):
            target = _frame_output(output, source=sources[min(index, len(sources) - 1)] if raw_size is None
                                   else first_source, index=index, option="-o")
            data, report = encode_frame(frame, name=name, output=target, pattern=pattern, raw_size=raw_size,
                                        pix_fmt=pix_fmt, budget_hint=previous, **(coding or {}))
            previous = report
            yield index, target, data, report

    def reported(index, report):
        item = report.as_dict()
        item["frame"] = index
        return item

    if output == STDIO or per_frame:
        # Before the first frame is read: standard output is usable, the first file can be made.
        first = _frame_output(output, source=sources[0] if raw_size is None and sources else first_source,
                              index=0, option="-o")
        prepare_outputs([first], sources, overwrite=overwrite, make_dirs=True, replace_existing=False)
        for index, target, data, report in frames():
            if per_frame:
                prepare_outputs([target], sources, overwrite=overwrite, make_dirs=True, replace_existing=False)
            write_output_bytes(target, data, overwrite=overwrite)
            yield reported(index, report)
        return
    # One stream file: nothing appears at the path until the last frame is in.
    prepare_outputs([output], sources, overwrite=overwrite, make_dirs=False)
    items = []
    with atomic_write(output, overwrite=overwrite) as handle:
        for index, _, data, report in frames():
            handle.write(data)
            items.append(reported(index, report))
    yield from items


# =====================================================================================
# Host side
# =====================================================================================

class _LeftFrames:
    """The left image of each frame: one image for all, a list in name order, or a template.

    :meth:`read_ahead` reads the next frame's image on a thread of its own while this
    frame decodes: a 640x480 decode keeps the two cores ~176 % busy, and reading its
    PNG took ~5 ms between decodes.  What the thread could not read (a file not written yet, or
    half written) is read again when its frame comes, so errors stay those of a plain read.
    """

    def __init__(self, left: str):
        self.template = left if uses_field(left, "index", "LEFT") else None
        self.paths = None if self.template else expand_inputs([left], extensions=IMAGE_EXTENSIONS, what="image")
        self._cached = None
        self._reader = None     # one thread, started by the first read_ahead
        self._ahead = None      # (index, path, future) of the image being read ahead

    def path(self, index: int) -> str:
        if self.template is not None:
            return expand_template(self.template, self.template, option="LEFT", index=index)
        if len(self.paths) == 1:
            return self.paths[0]
        if index >= len(self.paths):
            raise MismatchError(f"the stream has more frames than the {len(self.paths)} left images given "
                                f"(frame {index} has none)", path=display_name(self.paths[-1]))
        return self.paths[index]

    def read(self, index: int):
        from ..io import _images as imageio
        path = self.path(index)
        if self.template is None and len(self.paths) == 1:
            if self._cached is None:
                self._cached = imageio.read_image(path)[0]
            return path, self._cached
        ahead, self._ahead = self._ahead, None
        if ahead is not None and ahead[:2] == (index, path):
            try:
                stamp, image = ahead[2].result()
                if stamp == _file_stamp(path):   # not written to since the thread began reading it
                    return path, image
            except Exception:  # noqa: BLE001 -- read again below, where an error belongs to its frame
                pass
        return path, imageio.read_image(path)[0]

    def read_ahead(self, index: int) -> None:
        """Start reading frame ``index``'s left image in the background, when it has one of its own."""
        from concurrent.futures import ThreadPoolExecutor

        from ..io import _images as imageio
        if self.template is None and (len(self.paths) == 1 or index >= len(self.paths)):
            return
        path = self.path(index)
        if not os.path.isfile(path):
            return
        if self._reader is None:
            self._reader = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stereobudget-read")
        self._ahead = (index, path, self._reader.submit(lambda: (_file_stamp(path), imageio.read_image(path)[0])))

    def close(self) -> None:
        """Stop the reading thread (a command exits faster with no thread left)."""
        self._ahead = None
        if self._reader is not None:
            self._reader.shutdown(wait=True)
            self._reader = None

    def unused(self, frames: int) -> int:
        """Left images given that no frame used."""
        if self.template is not None or len(self.paths) == 1:
            return 0
        return max(0, len(self.paths) - frames)


def _file_stamp(path: str) -> tuple:
    """Size and modification time of a file: a file written to since has another."""
    status = os.stat(path)
    return status.st_size, status.st_mtime_ns


def decode_stream(left: str, samples: str, *, disparity: str | None = None, preview: str | None = None,
                  right: str | None = None, max_disp=None, min_disp: int | None = None,
                  method: str | None = None, overwrite: bool = False, max_memory: int | None = None,
                  disparity_format: str | None = None, synthesis: dict | None = None, depth: str | None = None,
                  points: str | None = None, calibration: str | None = None, frame: str | None = None,
                  temporal: bool = True) -> Iterator[dict]:
    """Decode every frame of a stream of ``.sbs`` frames in this process; yield a summary per frame.

    Parameters
    ----------
    left : str
        The left image of every frame; a folder or quoted glob of left images (taken in
        name order, one per frame); or a template using ``{index}`` (``'L/{index:05d}.png'``).
    samples : str
        A file of concatenated ``.sbs`` frames, or ``-`` for standard input (read one frame
        at a time, so an endless pipe is decoded as it arrives).
    disparity, preview, right : str, optional
        Outputs, as in :class:`~stereobudget.pipeline.DecodeJob`.  A template using ``{index}``
        (plus ``{stem}``/``{name}``/``{parent}`` of the frame's left image) writes one file
        per frame; ``-`` writes every frame to standard output, one image after another.
        A name that two frames would share (a plain name, or ``{stem}`` of one left image
        for all) is an error at the second of them.
    max_disp, min_disp, method, overwrite, max_memory, disparity_format, synthesis
        As in :class:`~stereobudget.pipeline.DecodeJob`; ``max_disp="auto"`` estimates the
        range of every frame on its own.
    depth, points, calibration, frame
        As in :class:`~stereobudget.pipeline.DecodeJob`; the calibration is read and its
        rectification maps computed for the first frame, then reused.  ``"auto"`` estimates
        the rectification on the first frame and reuses it, checking it every
        :data:`stereobudget.geometry.CHECK_EVERY` frames
        (:class:`~stereobudget.geometry.SelfRectifiedStream`).
    temporal : bool
        Each frame searches a band of disparities around the previous frame's
        (``Decoder(temporal=True)``, :class:`stereobudget.decoding.TemporalSearch`); False:
        every frame searches the whole range.  A frame of another size than the first is
        then an error.  With a given ``max_disp`` the swapped / not rectified checks (the
        range estimate) then run on the first frame only: one camera rig makes the stream.

    Yields
    ------
    dict
        The summary of :func:`stereobudget.pipeline.decode_file` for the frame, with ``frame``.

    Raises
    ------
    StereoBudgetError
        The first problem, naming its frame; earlier frames have been written.
    """
    from ..io._samples import read_samples

    decoder = None
    # --calibration auto: one estimate for the stream, checked as it goes.
    rectifier = None
    if calibration == "auto":
        from ..geometry._selfrect import SelfRectifiedStream
        rectifier = SelfRectifiedStream()
    if temporal:
        from ..decoding._decoders import Decoder
        decoder = Decoder(temporal=True)

    templates = {"disparity": disparity, "preview": preview, "right": right, "depth": depth, "points": points}
    lefts = _LeftFrames(left)
    stream_name = display_name(samples)
    inputs = [samples] if samples != STDIO else []
    index = -1
    written: dict[str, int] = {}        # output file -> the frame that wrote it
    # Before the first frame is read: the first frame's outputs can be written (standard
    # output open, folders there, names that fit), as for a single pair.
    first = {kind: _frame_output(value, source=lefts.path(0), index=0, option=f"--{kind}")
             for kind, value in templates.items()}
    check_job_outputs(DecodeJob(left=lefts.path(0), samples=stream_name, calibration=calibration, frame=frame,
                                **first))
    prepare_outputs([path for path in first.values() if path is not None], [lefts.path(0), *inputs],
                    overwrite=overwrite, make_dirs=True, replace_existing=False)
    try:
        for index, frame_bytes in enumerate(sample_frames(samples)):
            start = time.perf_counter()
            label = frame_label(stream_name, index) if index else stream_name
            left_path = lefts.path(index)
            outputs = {kind: _frame_output(value, source=left_path, index=index, option=f"--{kind}")
                       for kind, value in templates.items()}
            for kind, path in outputs.items():
                if path in (None, STDIO):
                    continue
                key = os.path.normpath(os.path.abspath(path))
                if key in written:
                    raise OptionError(f"frame {index} would write --{kind} {path} again (frame {written[key]} "
                                      "wrote it); put {index} in the name (e.g. 'out/{index:05d}.pfm') or write "
                                      "to '-'", path=stream_name)
                written[key] = index
            job = DecodeJob(left=left_path, samples=label, method=method, max_disp=max_disp, min_disp=min_disp,
                            overwrite=overwrite, max_memory=max_memory, disparity_format=disparity_format,
                            synthesis=synthesis, calibration=calibration, frame=frame, **outputs)
            check_job_outputs(job)
            replace = prepare_outputs(list(job.outputs.values()),
                                      [left_path, *inputs, *([job.calibration_file] if job.calibration_file else [])],
                                      overwrite=overwrite, make_dirs=True, replace_existing=False)
            t = time.perf_counter()
            left_path, left_image = lefts.read(index)
            lefts.read_ahead(index + 1)     # while this frame decodes
            sample_set = read_samples(frame_bytes, source=label)
            timings = {"read": time.perf_counter() - t}
            summary = decode_arrays(left_image, sample_set, job, left_name=display_name(left_path),
                                    samples_name=label, overwrite=replace, timings=timings, start=start,
                                    announce=index == 0, decoder=decoder, check_setup=not temporal or index == 0,
                                    self_rectifier=rectifier)
            summary["frame"] = index
            yield summary
    finally:
        lefts.close()
    unused = lefts.unused(index + 1)
    if unused:
        log.warning("warning: the stream ended after %d frame(s); %d left image(s) were not used",
                    index + 1, unused)

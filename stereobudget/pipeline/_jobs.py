"""One pair, one file, one frame: the encode and decode paths every front end calls.

:class:`EncodeJob` / :class:`DecodeJob` describe one file's work with plain, picklable
values.  :func:`encode_one` and :func:`decode_file` do it and raise on any problem (errors
keep their class and exit code); :func:`decode_arrays` is the part of a decode after
reading, which a frame stream calls with frames it has read itself.  ``sb-encode`` and
``sb-decode`` call these for a single file, the batch items
(:func:`stereobudget.batch.encode_job`, :func:`stereobudget.batch.decode_job`) wrap them
with the up-to-date rule, and :func:`stereobudget.batch.decode_stream` calls
:func:`decode_arrays` frame by frame.

Outputs are checked before any input is read and always written atomically; the
``after_write`` hook of a job runs inside the same uninterruptible step as the writes
(a batch records there what made the outputs).

This module imports neither numba nor OpenCV at import time: the camera-side
``sb-encode`` uses it.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Callable, Iterable

from ..io._atomic import STDIO, display_name, interrupts_deferred, written_together
from ..errors import MemoryLimitError, OptionError
from ..decoding._methods import DEFAULT_METHOD
from ._outputs import check_job_outputs, prepare_outputs

#: Called with a job's output paths once they are written, before an interrupt can land.
AfterWrite = Callable[[Iterable[str]], None]

log = logging.getLogger("stereobudget")


@dataclass(frozen=True)
class EncodeJob:
    """One ``sb-encode`` input.

    Attributes
    ----------
    source, output : str
        Right image (or ``-``) and sample file (or ``-``).
    pattern : SamplingPattern
    raw_size : (width, height) or None
    pix_fmt : str or None
    overwrite : bool
        Replace existing outputs (in a batch: redo even up-to-date jobs).
    batch : bool
        Batch semantics: skip up-to-date outputs, replace stale ones, create folders.
    coding : dict, optional
        Keyword arguments of :func:`stereobudget.encoding.encode_file` choosing the payload
        coding (``codec``, ``value_bits``, ``quality``, ``size``, ``size_fraction``).
    """

    source: str
    output: str
    pattern: object
    raw_size: tuple | None = None
    pix_fmt: str | None = None
    overwrite: bool = False
    batch: bool = False
    coding: dict | None = None

    @property
    def label(self) -> str:
        return display_name(self.source)


def encode_one(job: EncodeJob, *, after_write: AfterWrite | None = None) -> dict:
    """Encode one :class:`EncodeJob`'s image and write its sample file; raises on any problem.

    Returns
    -------
    dict
        ``input``, ``output`` and the fields of :class:`stereobudget.encoding.EncodeReport`
        (``epsilon``, sizes...).
    """
    from ..encoding import encode_file

    overwrite = prepare_outputs([job.output], [job.source], overwrite=job.overwrite, make_dirs=job.batch)
    # Output and record together (see decode_arrays); an encode takes milliseconds.
    with interrupts_deferred():
        report = encode_file(job.source, job.output, pattern=job.pattern, raw_size=job.raw_size,
                             pix_fmt=job.pix_fmt, overwrite=overwrite, **(job.coding or {}))
        if after_write is not None:
            after_write([job.output])
    result = {"input": report.source, "output": "<stdout>" if job.output == STDIO else job.output}
    result.update(report.as_dict())
    result["input"] = report.source
    return result


@dataclass(frozen=True)
class DecodeJob:
    """One ``sb-decode`` pair.

    Attributes
    ----------
    left, samples : str or None
        Left image and sample file (``-`` = standard input for one of them).  None, with
        ``problem`` set, is a pairing failure reported as a failed item.
    disparity, preview, right : str or None
        Outputs: disparity map (format by extension), colour preview PNG, recovered right
        image Î2 (PNG/TIFF, input's channels and bit depth; ``-`` = standard output).
    max_disp : int, "auto" or None
        Largest disparity searched; None or ``"auto"``: estimated from the pair
        (:func:`stereobudget.decoding.estimate_disparity_range`).
    min_disp : int or None
        Smallest disparity searched; None: the estimate's when ``max_disp`` is estimated,
        else 0.
    method : str or None
        Decoder (None: the library default).
    overwrite, batch : bool
        As in :class:`EncodeJob`.
    threads : int or None
        Cap on numba threads in the worker.
    problem : str or None
        Why this pair cannot be decoded (set by the pairing step).
    max_memory : int or None
        Memory limit of the decode in bytes (None: 75 % of the available memory).
    disparity_format : {"pfm", "png"} or None
        Format of a disparity map written to standard output (``disparity="-"``; None: PFM).
    synthesis : dict or None
        Keyword arguments of :class:`stereobudget.synthesis.SynthesisParams` for the
        recovered right image (None: the defaults); plain values, so that the job stays
        light to build and to send to a worker.
    calibration : str or None
        Stereo calibration file (:func:`stereobudget.geometry.read_calibration`): the pair
        is rectified at the host and decoded in the rectified frame.  ``"auto"``: the
        rectification is estimated from the pair
        (:func:`stereobudget.geometry.self_rectification`; no metric scale).
    depth, points : str or None
        Metric outputs (need ``calibration``): depth in metres (``.tif``/``.pfm``/``.npy``
        float32, ``.png`` 16-bit millimetres) and a binary PLY point cloud.
    frame : {"rectified", "raw"} or None
        Pixel grid of the disparity, preview and depth maps with a calibration; None:
        disparity and preview in the rectified left frame, depth in the raw one.
    """

    left: str | None
    samples: str | None
    disparity: str | None = None
    preview: str | None = None
    right: str | None = None
    max_disp: int | str | None = None
    min_disp: int | None = None
    method: str | None = None
    overwrite: bool = False
    batch: bool = False
    threads: int | None = None
    problem: str | None = None
    max_memory: int | None = None
    disparity_format: str | None = None
    synthesis: dict | None = None
    calibration: str | None = None
    depth: str | None = None
    points: str | None = None
    frame: str | None = None

    @property
    def label(self) -> str:
        return display_name(self.left if self.left is not None else self.samples)

    @property
    def calibration_file(self) -> str | None:
        """The calibration file the job reads (None without one, or with ``"auto"``)."""
        return None if self.calibration in (None, "auto") else self.calibration

    @property
    def outputs(self) -> dict:
        return {k: v for k, v in (("disparity", self.disparity), ("preview", self.preview),
                                  ("right", self.right), ("depth", self.depth), ("points", self.points))
                if v is not None}


def _as_image_dtype(image, dtype):
    """Î2 in the input's bit depth; float images are in 8-bit units (the library convention)."""
    import numpy as np

    image = np.asarray(image)
    dtype = np.dtype(dtype)
    if image.dtype == dtype:
        return image
    if image.dtype.kind in "ui":
        scale = (257.0 if dtype == np.uint16 else 1.0) / (257.0 if image.dtype == np.uint16 else 1.0)
    else:
        scale = 257.0 if dtype == np.uint16 else 1.0
    top = np.iinfo(dtype).max
    values = np.nan_to_num(image.astype(np.float64) * scale, nan=0.0)
    return np.clip(np.rint(values), 0, top).astype(dtype)


def recover_right_image(left, disparity, samples, *, synthesis: dict | None = None):
    """Call :func:`stereobudget.synthesis.recover_right` with ``SynthesisParams(**synthesis)``;
    returns ``(image, extras)``.

    ``extras`` holds the PSNR at the samples (dB; null when infinite), ``holes_fraction``
    and, under ``"_timings"``, the synthesis stages.
    """
    import math

    from ..synthesis._recover import SynthesisParams, recover_right

    recovered = recover_right(left, disparity, samples, params=SynthesisParams(**(synthesis or {})))
    extras = {}
    for key in ("psnr_at_samples_before_enhancement", "psnr_at_samples_before_reinsertion"):
        value = float(getattr(recovered, key))
        # JSON has no inf/NaN: an infinite PSNR (exact match) or an undefined one is null.
        extras[key] = value if math.isfinite(value) else None
    if recovered.holes.size:
        extras["holes_fraction"] = float(recovered.holes.mean())
    for stage, seconds in recovered.timings.items():
        extras.setdefault("_timings", {})[f"right_{stage}"] = seconds
    return recovered.image, extras


def decode_file(job: DecodeJob, *, after_write: AfterWrite | None = None) -> dict:
    """Decode one pair and write its outputs; raises on any problem.

    This is the single-file path of ``sb-decode`` (errors keep their class and exit
    code); batches use :func:`stereobudget.batch.decode_job`, which wraps it.
    ``after_write`` is called with the output paths inside the step that writes them.

    Returns
    -------
    dict
        JSON-able summary: inputs, size, channels, dtype, epsilon, method, disparity
        range searched and found, ``valid_fraction``, ``timings`` per stage (``read``,
        ``validate``, the decoder's stages, ``right``, ``write``, ``total``), outputs,
        and any extra facts the decoder or the synthesis reports.
    """
    start = time.perf_counter()
    if job.problem:
        raise OptionError(job.problem, path=job.label)
    if job.left == STDIO and job.samples == STDIO:
        raise OptionError("only one of LEFT and SAMPLES can be '-' (standard input)")
    outputs = job.outputs
    check_job_outputs(job)
    inputs = [job.left, job.samples] + ([job.calibration_file] if job.calibration_file else [])
    overwrite = prepare_outputs(list(outputs.values()), inputs, overwrite=job.overwrite,
                                make_dirs=job.batch)
    from ..io import _images as imageio
    from ..io._samples import load_samples
    timings: dict = {}

    t = time.perf_counter()
    left, _ = imageio.read_image(job.left)
    samples = load_samples(job.samples)
    timings["read"] = time.perf_counter() - t
    return decode_arrays(left, samples, job, left_name=display_name(job.left),
                         samples_name=display_name(job.samples), overwrite=overwrite, timings=timings,
                         start=start, after_write=after_write, announce=not job.batch)


def decode_arrays(left, samples, job: DecodeJob, *, left_name: str, samples_name: str, overwrite: bool,
                  timings: dict, start: float, after_write: AfterWrite | None = None,
                  announce: bool = False, decoder=None, check_setup: bool = True,
                  self_rectifier=None) -> dict:
    """The part of :func:`decode_file` after reading: decode ``left`` + ``samples``, write ``job``'s outputs.

    The outputs have been checked (``overwrite`` is the flag to write them with);
    ``timings`` holds the stages so far and ``start`` the job's start
    (``time.perf_counter``).  ``announce`` says before the first kernel runs that numba
    may compile for minutes.  ``decoder``: the :class:`~stereobudget.decoding.Decoder` to
    decode with (a stream's temporal one; default the process's shared one).
    ``check_setup=False`` with a given ``max_disp`` skips the range estimate, which then only
    serves the swapped / not rectified warnings (a stream checks its first frame).
    ``self_rectifier``: with ``job.calibration == "auto"``, the
    :class:`~stereobudget.geometry.SelfRectifiedStream` that keeps a stream's estimate
    (default: one estimate for this pair).  Returns the summary of :func:`decode_file`.
    """
    from ..io import _images as imageio
    outputs = job.outputs
    # The decoder (numba) loads only once both inputs have been read successfully.
    import math

    import numpy as np

    from ..decoding import _decoders as decoders
    from ..io import _disparity as dispio
    from ..errors import CalibrationError, MismatchError
    t = time.perf_counter()
    from ..decoding import _checks as checks
    from ..decoding import _disprange as disprange
    from .._kernels._first_run import compile_notice
    auto = disprange.is_auto(job.max_disp)
    method = job.method or DEFAULT_METHOD
    raw_left, raw_samples = left, samples
    rectification, auto_facts = None, None
    try:
        # Sizes and types first (the estimate needs them to agree), then the range.
        decoders.check_inputs(left, samples, min_disp=0, max_disp=1)
        timings["validate"] = time.perf_counter() - t
        if announce:
            # After an install or upgrade numba compiles for minutes: say so before the
            # first kernel runs, which --calibration auto's estimate already runs (a batch
            # says it once, in the command).
            from .._kernels._first_run import announce_first_compile
            if announce_first_compile() and method == "hybrid":
                # The second core compiles the decode's later kernels meanwhile.
                from ..warm import start_hybrid_tail
                start_hybrid_tail("gray" if left.ndim == 2 else "rgb")
        if job.calibration is not None:
            # Rectified at the host: I1 resampled, each sample placed where it lands
            # (maps computed once per calibration file and image size, or once per stream
            # from the pair itself).
            from ..geometry import _rectify as rectify
            t = time.perf_counter()
            if job.calibration == "auto":
                from ..geometry._selfrect import SelfRectifiedStream
                rectifier = self_rectifier if self_rectifier is not None else SelfRectifiedStream(check_every=0)
                rectification, auto_facts = rectifier.for_frame(left, samples)
                timings["self_rectify"] = time.perf_counter() - t
            else:
                rectification = rectify.rectification_for(job.calibration, left.shape[1], left.shape[0])
                timings["rectify_maps"] = time.perf_counter() - t
            t = time.perf_counter()
            left = rectify.rectify_left(left, rectification)
            samples = rectify.rectify_samples(samples, rectification)
            timings["rectify"] = time.perf_counter() - t
        t = time.perf_counter()
        if auto or check_setup:
            with compile_notice(method):    # names the method, not the range estimate
                min_disp, max_disp, estimate = disprange.resolve_range(left, samples, max_disp=job.max_disp,
                                                                       min_disp=job.min_disp)
        else:
            min_disp, max_disp, estimate = (0 if job.min_disp is None else int(job.min_disp),
                                            int(job.max_disp), None)
        timings["estimate_range"] = time.perf_counter() - t
        decoders.check_inputs(left, samples, min_disp=min_disp, max_disp=max_disp)
    except (MismatchError, OptionError) as exc:
        raise type(exc)(f"{exc.message} ({samples_name})", path=left_name) from None
    except CalibrationError as exc:
        if job.calibration != "auto":
            raise
        raise CalibrationError(f"--calibration auto: {exc.message} ({samples_name})", path=left_name) from None
    if auto:
        log.info("%s: disparity range %d..%d (estimated from %d matches in %.2f s)", left_name, min_disp,
                 max_disp, estimate.votes, estimate.seconds)

    # A process that decodes file after file: each decode takes over the last one's memory.
    decoder = decoder or decoders.shared_decoder()
    try:
        result = decoder.decode(left, samples, max_disp=max_disp, min_disp=min_disp, method=method,
                                max_memory=job.max_memory)
    except MemoryLimitError as exc:
        raise MemoryLimitError(exc.message, path=left_name) from None
    except OptionError as exc:
        # What the sample file does not allow (a stride-1 Bayer mosaic, --method against its pattern).
        raise OptionError(exc.message, path=exc.path or samples_name) from None
    except MismatchError as exc:
        raise MismatchError(f"{exc.message} ({samples_name})", path=left_name) from None
    widened_from = None
    if auto:
        # An estimate built from few confident samples on the nearest surfaces falls
        # short of them: their pixels then pile up at the top.  Decode once more, wider.
        wider = disprange.widened_max(result.disparity, min_disp=min_disp, max_disp=max_disp,
                                      width=int(left.shape[1]))
        if wider is not None:
            log.info("%s: %.1f %% of the pixels at the top of the estimated range %d..%d: decoding again "
                     "over %d..%d", left_name, 100 * disprange.top_share(result.disparity, max_disp=max_disp),
                     min_disp, max_disp, min_disp, wider)
            timings.update({f"{k}_first_range": v for k, v in result.timings.items()})
            try:
                result = decoder.decode(left, samples, max_disp=wider, min_disp=min_disp, method=method,
                                        max_memory=job.max_memory)
                widened_from, max_disp = max_disp, wider
            except MemoryLimitError:
                log.info("%s: the wider range does not fit the memory limit; keeping %d..%d", left_name,
                         min_disp, max_disp)
    disparity = result.disparity
    timings.update(result.timings)

    extras = {}
    right_image = None
    if job.right is not None:
        t = time.perf_counter()
        right_image, extras = recover_right_image(left, disparity, samples, synthesis=job.synthesis)
        right_image = _as_image_dtype(right_image, left.dtype)
        timings.update(extras.pop("_timings", {}))
        timings["right"] = time.perf_counter() - t

    t = time.perf_counter()
    psnr = checks.psnr_at_samples(left, disparity, samples)
    warnings = checks.setup_warnings(estimate) + checks.result_warnings(
        disparity, min_disp=min_disp, max_disp=max_disp, psnr=psnr, auto_range=auto,
        # A flat pair matches itself anywhere: no_texture says it, not left_is_samples.
        zero_psnr=(checks.psnr_at_zero_disparity(left, samples)
                   if estimate is None or estimate.textured_fraction >= checks.MIN_TEXTURED_SHARE else None))
    timings["checks"] = time.perf_counter() - t

    t = time.perf_counter()
    shown, depth, cloud = disparity, None, None
    if rectification is not None:
        from ..geometry import _rectify as rectify
        if job.frame == "raw":
            shown = rectify.raw_left_disparity(disparity, rectification)
        if job.depth is not None:
            depth = rectify.depth_map(disparity, rectification, frame=job.frame or "raw")
        if job.points is not None:
            cloud = rectify.point_cloud(disparity, rectification, raw_left)
        timings["metric"] = time.perf_counter() - t
        t = time.perf_counter()
    # The outputs and the record of what made them are written together: a batch
    # interrupted in between would otherwise redo a finished file.  The outputs are all
    # or none: each goes to its temporary file and all are moved into place at the end,
    # so one that cannot be written (a full disk) leaves none of them.
    with interrupts_deferred():
        with written_together():
            if job.disparity is not None:
                dispio.write_disparity(job.disparity, shown, overwrite=overwrite,
                                       stream_format=((job.disparity_format or "pfm") if job.disparity == STDIO
                                                      else None))
            if job.preview is not None:
                dispio.write_preview(job.preview, shown, min_disp=min_disp, max_disp=max_disp,
                                     overwrite=overwrite)
            if depth is not None:
                from ..geometry._output import write_depth
                write_depth(job.depth, depth, overwrite=overwrite)
            if cloud is not None:
                from ..geometry._output import write_ply
                write_ply(job.points, *cloud, overwrite=overwrite)
            if right_image is not None:
                imageio.write_image(job.right, right_image,
                                    channel_order="rgb" if right_image.ndim == 3 else "gray", overwrite=overwrite)
        if after_write is not None:
            after_write(outputs.values())
    timings["write"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - start

    valid = np.isfinite(disparity)
    summary = {
        "status": "ok", "left": left_name, "samples": samples_name,
        "width": int(left.shape[1]), "height": int(left.shape[0]),
        "channels": 1 if left.ndim == 2 else int(left.shape[2]), "dtype": str(left.dtype),
        "sample_count": int(raw_samples.values.shape[0]), "epsilon": raw_samples.epsilon,
        "pixel_fraction": raw_samples.epsilon,
        "pattern": raw_samples.pattern.kind, "stride_x": raw_samples.pattern.stride_x,
        "stride_y": raw_samples.pattern.stride_y, "codec": raw_samples.codec,
        "value_bits": raw_samples.value_bits or 8 * raw_samples.values.dtype.itemsize,
        "method": result.method, "min_disp": int(min_disp), "max_disp": int(max_disp),
        "range_source": "estimated" if auto else "given",
        "range_estimate": None if estimate is None else estimate.summary(),
        "range_widened_from": widened_from,
        "psnr_at_samples": psnr if math.isfinite(psnr) else None,
        "warnings": [w.as_dict() for w in warnings],
        "disparity_range": ([float(disparity[valid].min()), float(disparity[valid].max())]
                            if valid.any() else None),
        "valid_fraction": float(valid.mean()),
        "timings": {k: round(float(v), 4) for k, v in timings.items()},
        "outputs": {k: ("<stdout>" if v == STDIO else v) for k, v in outputs.items()},
    }
    if rectification is not None:
        # Which pixel grid each map is on: the pair is decoded in the rectified left frame.
        summary["frame"] = {"disparity": job.frame or "rectified", "depth": job.frame or "raw",
                            "right": "rectified"}
        summary["calibration"] = {**rectification.calibration.summary(), **rectification.summary(),
                                  "samples_placed": int(samples.values.shape[0])}
        if auto_facts is not None:
            # Estimated from the pair: the baseline is a unit, not metres.
            for key in ("baseline_m", "doffs_px"):
                summary["calibration"].pop(key, None)
            summary["calibration"]["self_rectification"] = auto_facts
        if cloud is not None:
            summary["points"] = int(len(cloud[0]))
        if depth is not None:
            finite = depth[np.isfinite(depth)]
            summary["depth_range_m"] = [float(finite.min()), float(finite.max())] if finite.size else None
    decoder_summary = result.summary() if hasattr(result, "summary") else {}
    for key, value in decoder_summary.items():
        if key not in summary and key not in ("timings",):
            summary[key] = value
    for key, value in extras.items():
        summary.setdefault(key, value)
    return summary


__all__ = ["EncodeJob", "encode_one", "DecodeJob", "recover_right_image", "decode_file", "decode_arrays"]

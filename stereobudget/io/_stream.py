"""Frame streams: concatenated ``.sbs`` files, and headerless raw frames one after another.

A camera sends frames continuously.  A ``.sbs`` file is self-delimiting (its header gives
the header and payload lengths), so a stream of sample frames is simply their
concatenation (``cat a.sbs b.sbs``); a raw stream is frames of one fixed size back to
back.  The readers here take one frame at a time from a file or standard input, so an
endless pipe is decoded as it arrives and memory holds one frame.

Framing errors end a stream: once a header is damaged or a frame is cut short there is
no reliable way to find the next frame.  Every error names the frame (``frame 3``,
counting from 0).

Like :mod:`stereobudget.io._rawgrid`, this module does not import numpy: the camera-side
raw stream stays as light as one raw frame.
"""

from __future__ import annotations

import contextlib
import os
import struct
from typing import BinaryIO, Iterator

from ..errors import ImageReadError, NotASampleFileError, TruncatedFileError
from ._atomic import display_name, reading_error, stdin_or

#: Offsets of the fields that frame a ``.sbs`` file (docs/format.md).
_HEADER_LENGTH_AT = 10
_PAYLOAD_LENGTH_AT = 64


def frame_label(name: str, index: int) -> str:
    """How frame ``index`` of the stream ``name`` is named in messages."""
    return f"{name} frame {index}"


@contextlib.contextmanager
def _open_input(source, error: type) -> Iterator[BinaryIO]:
    """A binary reader of ``source`` (a path, or ``-`` for standard input), errors as ``error``."""
    name = display_name(source)
    if str(source) == "-":
        stdin = stdin_or(error)
        if stdin.isatty():
            raise error("refusing to read binary data from a terminal; pipe or redirect a file", path=name)
        yield stdin
        return
    try:
        handle = open(source, "rb")
    except OSError as exc:
        raise reading_error(exc, error, name) from None
    with handle:
        yield handle


def _read_exactly(stream: BinaryIO, count: int) -> bytes:
    """Up to ``count`` bytes: fewer only at the end of the stream (pipes return short reads)."""
    chunks, got = [], 0
    while got < count:
        chunk = stream.read(count - got)
        if not chunk:
            break
        chunks.append(chunk)
        got += len(chunk)
    return b"".join(chunks)


def sample_frames(source, *, name: str | None = None) -> Iterator[bytes]:
    """The ``.sbs`` files of a stream, one frame's bytes at a time, in order.

    Each frame is checked only as far as its framing (signature, header checksum and
    fields, payload length); :func:`stereobudget.io.read_samples` checks the rest.

    Parameters
    ----------
    source : str or os.PathLike
        A file of one or more concatenated ``.sbs`` frames, or ``-`` for standard input.
    name : str, optional
        Name of the stream in messages (default: the path, ``<stdin>`` for ``-``).

    Yields
    ------
    bytes
        One complete frame (header and payload).

    Raises
    ------
    SampleFileError
        The subclass naming the first framing problem, with the frame's index; an empty
        stream is a :class:`~stereobudget.errors.TruncatedFileError`.
    """
    from ._samples import HEADER_SIZE_V1_0, _parse_header

    name = name or display_name(source)
    with _open_input(source, NotASampleFileError) as stream:
        index = 0
        while True:
            label = frame_label(name, index) if index else name
            head = _read_exactly(stream, HEADER_SIZE_V1_0)
            if not head:
                if index == 0:
                    raise TruncatedFileError("empty file (0 bytes)", path=name)
                return
            if len(head) < HEADER_SIZE_V1_0:
                # Let the parser say what the bytes are (not a .sbs file, a cut header...).
                _parse_header(memoryview(head), label)
            header_length = struct.unpack_from("<H", head, _HEADER_LENGTH_AT)[0]
            header = head + _read_exactly(stream, max(0, header_length - HEADER_SIZE_V1_0))
            declared = struct.unpack_from("<Q", head, _PAYLOAD_LENGTH_AT)[0]
            # The header's own checks (signature, version, checksum, fields) come first;
            # only then is its payload length trusted for reading.
            _parse_header(memoryview(header), label, file_size=len(header) + declared)
            payload = _read_exactly(stream, declared)
            if len(payload) < declared:
                raise TruncatedFileError(f"{f'frame {index}' if index else 'file'} is truncated: payload has "
                                         f"{len(payload)} of "
                                         f"{declared} bytes ({declared - len(payload)} missing)", path=name)
            yield header + payload
            index += 1


def raw_frames(source, *, width: int, height: int, pix_fmt: str, name: str | None = None) -> Iterator[bytes]:
    """The headerless frames of a raw stream (``width`` x ``height`` ``pix_fmt`` each), in order.

    Raises
    ------
    ImageReadError
        Unknown pixel format, bad size, an empty input, or a last frame that is cut short
        (the message gives its index and byte count).
    """
    from ._rawgrid import raw_frame_layout

    name = name or display_name(source)
    channels, value_bytes, _ = raw_frame_layout(width=width, height=height, pix_fmt=pix_fmt, name=name)
    frame_bytes = width * height * channels * value_bytes
    with _open_input(source, ImageReadError) as stream:
        index = 0
        while True:
            frame = _read_exactly(stream, frame_bytes)
            if len(frame) == frame_bytes:
                yield frame
                index += 1
            elif not frame and index:
                return
            elif index == 0:
                raise ImageReadError(f"raw {pix_fmt} {width}x{height} frame must be exactly {frame_bytes} "
                                     f"bytes, got {len(frame)} (less than one frame)", path=name)
            else:
                raise ImageReadError(f"raw {pix_fmt} {width}x{height} frames are {frame_bytes} bytes each; "
                                     f"frame {index} is cut short at {len(frame)} bytes", path=name)


def holds_several_frames(path) -> bool:
    """Whether the regular file ``path`` holds a ``.sbs`` frame followed by the signature of another.

    Reads only the first header; False for ``-``, a pipe, or a file that is not a
    readable ``.sbs`` file (the reader reports those).
    """
    from ._samples import HEADER_SIZE_V1_0, MAGIC

    if str(path) == "-":
        return False
    try:
        import stat
        with open(path, "rb") as handle:
            if not stat.S_ISREG(os.fstat(handle.fileno()).st_mode):
                return False
            head = handle.read(HEADER_SIZE_V1_0)
            if len(head) < HEADER_SIZE_V1_0 or not head.startswith(MAGIC):
                return False
            header_length = struct.unpack_from("<H", head, _HEADER_LENGTH_AT)[0]
            payload_length = struct.unpack_from("<Q", head, _PAYLOAD_LENGTH_AT)[0]
            handle.seek(header_length + payload_length)
            # Another signature right after the first frame; other trailing bytes are the
            # single-file reader's "unexpected bytes".
            return handle.read(len(MAGIC)) == MAGIC
    except (OSError, OverflowError, ValueError):
        return False

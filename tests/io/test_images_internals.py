"""White-box tests of stereobudget.io._images: the normalisation step and where an interrupt may land
while a decoder's stderr is captured."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest

from stereobudget.io import _images as images
from stereobudget.io import read_image


def rgb_image(h=7, w=9):
    return np.random.default_rng(0).integers(0, 255, (h, w, 3), endpoint=True, dtype=np.uint8)


def png_bytes(rgb: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]))
    assert ok
    return buf.tobytes()


def test_single_channel_3d_arrays_are_squeezed():
    # No common file format decodes to (H, W, 1) here, so check the normalisation step itself.
    gray = rgb_image()[:, :, :1]
    image, order = images._normalise(gray, name="x", bgr=True)
    assert order == "gray" and image.shape == gray.shape[:2]


def _fd2_identity():
    st = os.fstat(2)
    return st.st_dev, st.st_ino


@pytest.mark.parametrize("where", ["after the swap-in", "in the decoder", "in the final flush"])
def test_an_interrupt_while_decoder_stderr_is_captured_leaves_fd2_restored(where, monkeypatch):
    # While an image is decoded, fd 2 points at a temporary file.  Wherever a Ctrl-C /
    # SIGTERM lands meanwhile, fd 2 must be stderr again when the KeyboardInterrupt leaves
    # read_image: the command's "interrupted" line is written after it (a CI run lost it).
    real_dup2 = os.dup2
    calls = []

    def dup2_then_interrupt(fd, fd2, *args, **kwargs):
        real_dup2(fd, fd2, *args, **kwargs)
        calls.append(fd2)
        if len(calls) == 1:         # the swap-in: the signal arrives just as it returns
            raise KeyboardInterrupt

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    if where == "after the swap-in":
        monkeypatch.setattr(images.os, "dup2", dup2_then_interrupt)
    elif where == "in the decoder":
        monkeypatch.setattr(images, "_decode_with_opencv", interrupt)
    else:
        monkeypatch.setattr(images, "_flush_quietly", interrupt)
    before = _fd2_identity()
    with pytest.raises(KeyboardInterrupt):
        read_image(png_bytes(rgb_image()))
    monkeypatch.undo()
    assert _fd2_identity() == before
    if where == "after the swap-in":
        assert calls == [2, 2]      # swapped in, and back

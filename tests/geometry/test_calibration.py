"""Calibration files: the three formats agree, and every malformed or inconsistent file is refused in one line."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from stereobudget.errors import CalibrationError
from stereobudget.geometry import check_image_size, read_calibration

K1 = np.array([[520.0, 0, 161.5], [0, 520.0, 119.5], [0, 0, 1]])
K2 = np.array([[515.0, 0, 158.0], [0, 516.0, 121.0], [0, 0, 1]])
D1 = np.array([0.08, -0.01, 0.0, 0.0, 0.0])
D2 = np.array([-0.06, 0.0, 0.0, 0.0, 0.0])
R = cv2.Rodrigues(np.array([0.01, -0.02, 0.005]))[0]
T = np.array([-0.12, 0.002, 0.001])


def write_filestorage(path, **overrides):
    values = dict(M1=K1, D1=D1[None], M2=K2, D2=D2[None], R=R, T=T[:, None])
    values.update(overrides)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in values.items():
        if value is not None:
            storage.write(key, value)
    storage.release()
    return str(path)


def write_json(path, **overrides):
    values = dict(M1=K1.tolist(), D1=D1.tolist(), M2=K2.tolist(), D2=D2.tolist(), R=R.tolist(), T=T.tolist(),
                  image_size=[320, 240])
    values.update(overrides)
    path.write_text(json.dumps({k: v for k, v in values.items() if v is not None}))
    return str(path)


MIDDLEBURY = ("cam0=[1000.5 0 150.25; 0 1000.5 110; 0 0 1]\ncam1=[1000.5 0 170.25; 0 1000.5 110; 0 0 1]\n"
              "doffs=20\nbaseline=193.001\nwidth=320\nheight=240\nndisp=70\nisint=0\nvmin=23\nvmax=60\n")


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_filestorage_and_json_agree(tmp_path, suffix):
    a = read_calibration(write_filestorage(tmp_path / f"stereo{suffix}", image_width=320, image_height=240))
    b = read_calibration(write_json(tmp_path / "stereo.json"))
    for name in ("M1", "D1", "M2", "D2", "R", "T"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-12, err_msg=name)
    assert a.image_size == b.image_size == (320, 240)
    assert a.baseline == pytest.approx(np.linalg.norm(T))
    assert not a.rectified


def test_unit_converts_to_metres(tmp_path):
    calibration = read_calibration(write_json(tmp_path / "mm.json", T=(T * 1000).tolist(), unit="mm"))
    np.testing.assert_allclose(calibration.T, T)


def test_middlebury_calib_txt(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_text(MIDDLEBURY)
    calibration = read_calibration(str(path))
    assert calibration.rectified
    assert calibration.baseline == pytest.approx(0.193001)
    assert calibration.doffs == pytest.approx(20.0)
    assert calibration.image_size == (320, 240)
    np.testing.assert_array_equal(calibration.R, np.eye(3))


@pytest.mark.parametrize("text, field", [
    ("%YAML:1.0\nM1: [1, 2\n", "not a readable OpenCV YAML/XML file: line 2: Missing , between the elements"),
    ("", "empty file"),
    ("hello", "not a calibration file"),
])
def test_unreadable_files(tmp_path, text, field):
    path = tmp_path / ("stereo.yml" if text.startswith("%") else "stereo.txt")
    path.write_text(text)
    with pytest.raises(CalibrationError, match=field) as info:
        read_calibration(str(path))
    assert info.value.exit_code == 13
    assert str(info.value).startswith(str(path))
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("m1, reason", [
    ("[1, 2, 3]", "isMap"),                                                        # a sequence, not a matrix map
    ("!!opencv-matrix {rows: 3, cols: 3, dt: d, data: [1, 2]}", "nelems"),         # too few elements
    ("!!opencv-matrix {rows: 3, cols: 3, dt: q, data: [1, 2, 3, 4, 5, 6, 7, 8, 9]}", "data type"),
    ("!!opencv-matrix {rows: 100000, cols: 100000, dt: d, data: [1]}", "allocate"),  # 80 GB declared
])
def test_opencv_nodes_it_cannot_read_are_named(tmp_path, m1, reason):
    # OpenCV asserts on such nodes; the file and the field are still told in one line.
    text = open(write_filestorage(tmp_path / "ok.yml")).read()
    start = text.index("M1:")
    end = text.index("D1:")
    path = tmp_path / "stereo.yml"
    path.write_text(text[:start] + f"M1: {m1}\n" + text[end:])
    with pytest.raises(CalibrationError, match=f"M1 is not a readable matrix: .*{reason}") as info:
        read_calibration(str(path))
    assert str(info.value).startswith(str(path) + ": ") and "\n" not in str(info.value)


def test_json_nested_too_deep_is_not_valid_json(tmp_path):
    path = tmp_path / "deep.json"
    path.write_text('{"M1": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(CalibrationError, match="not valid JSON"):
        read_calibration(str(path))


def test_a_baseline_too_large_for_a_norm_is_refused_without_a_warning(tmp_path):
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(CalibrationError, match="T is too large"):
            read_calibration(write_json(tmp_path / "far.json", T=[-1e308, 0.0, 0.0]))


def test_byte_order_mark_and_empty_name(tmp_path):
    path = tmp_path / "calib.txt"
    path.write_bytes(b"\xef\xbb\xbf" + MIDDLEBURY.encode())        # as Windows editors save UTF-8
    assert read_calibration(str(path)).rectified
    with pytest.raises(CalibrationError, match="an empty file name"):
        read_calibration("")


@pytest.mark.parametrize("overrides, field", [
    (dict(T=None), "T is missing"),
    (dict(M1=np.eye(2)), "M1 must be 3x3"),
    (dict(D2=np.zeros((1, 3))), "D2 has 3 coefficients"),
    (dict(R=np.diag([1.0, 1.0, -1.0])), "R is not a rotation"),
    (dict(R=2 * np.eye(3)), "R is not a rotation"),
    (dict(M2=np.array([[-500.0, 0, 1], [0, 500, 1], [0, 0, 1]])), "M2: focal lengths must be positive"),
    (dict(T=np.array([[0.0], [0.0], [0.0]])), "T is zero"),
    (dict(T=np.array([[-0.01], [0.2], [0.0]])), "not mostly along x"),
    (dict(M1=np.array([[np.nan, 0, 1], [0, 1, 1], [0, 0, 1]])), "M1 holds a non-finite"),
])
def test_malformed_fields_are_named(tmp_path, overrides, field):
    path = write_filestorage(tmp_path / "stereo.yml", **overrides)
    with pytest.raises(CalibrationError, match=field) as info:
        read_calibration(path)
    assert str(info.value).startswith(path + ": ")


def test_wrong_baseline_sign_is_refused(tmp_path):
    path = write_filestorage(tmp_path / "swapped.yml", T=-T[:, None])
    with pytest.raises(CalibrationError, match=r"T\[0\] = \+0.12 m is positive: .*swapped"):
        read_calibration(path)
    middlebury = tmp_path / "calib.txt"
    middlebury.write_text(MIDDLEBURY.replace("baseline=193.001", "baseline=-193.001"))
    with pytest.raises(CalibrationError, match="baseline -193.001 must be positive"):
        read_calibration(str(middlebury))


@pytest.mark.parametrize("old, new, field", [
    ("doffs=20", "doffs=35", "doffs 35 disagrees"),
    ("width=320\n", "", "width is missing"),
    ("cam1=[1000.5 0 170.25; 0 1000.5 110; 0 0 1]", "cam1=[1000.5 0 170.25; 0 1000.5 110]", "cam1 must be a 3x3"),
    ("cam1=[1000.5 0 170.25; 0 1000.5 110; 0 0 1]", "cam1=[1000.5 0 170.25; 0 1000.5 111; 0 0 1]",
     "not a rectified pair"),
    ("baseline=193.001", "baseline=abc", "baseline is not a number"),
])
def test_middlebury_inconsistencies(tmp_path, old, new, field):
    path = tmp_path / "calib.txt"
    path.write_text(MIDDLEBURY.replace(old, new))
    with pytest.raises(CalibrationError, match=field):
        read_calibration(str(path))


def test_another_image_size_is_refused(tmp_path):
    calibration = read_calibration(write_json(tmp_path / "stereo.json"))
    check_image_size(calibration, 320, 240)
    with pytest.raises(CalibrationError, match=r"calibrated for 320x240 images but the left image is 640x480 "
                                               r"\(2x its size"):
        check_image_size(calibration, 640, 480)
    # Without a stated size, principal points far outside the image give it away.
    unsized = read_calibration(write_filestorage(tmp_path / "stereo.yml"))
    check_image_size(unsized, 320, 240)
    with pytest.raises(CalibrationError, match=r"principal point .* outside the 80x60 image"):
        check_image_size(unsized, 80, 60)

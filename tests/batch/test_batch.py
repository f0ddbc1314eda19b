"""Batch processing (issue 6): input expansion, templates, pairing, make-style skipping,
process pools, dask, failures that do not stop a batch, resuming a killed batch, pipes."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from click.testing import CliRunner

from stereobudget import batch
from stereobudget.cli.decode import decode_command
from stereobudget.io import load_samples, save_samples
from stereobudget.encoding import encode_image
from stereobudget.io import read_disparity
from stereobudget.errors import NotASampleFileError, OptionError
from stereobudget.sampling import SamplingPattern

BIN = Path(sys.executable).parent
SB_ENCODE, SB_DECODE = str(BIN / "sb-encode"), str(BIN / "sb-decode")
MAX_DISP = 12


def motorcycle(scale=8):
    skdata = pytest.importorskip("skimage.data")
    left, right, _ = skdata.stereo_motorcycle()
    size = (left.shape[1] // scale, left.shape[0] // scale)
    return (cv2.resize(left, size, interpolation=cv2.INTER_AREA),
            cv2.resize(right, size, interpolation=cv2.INTER_AREA))


def write_png(path, rgb):
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1]))
    return path


def make_pairs(folder: Path, count: int, *, scale=8, stride=4):
    """``folder/L/f{i}.png`` and ``folder/S/f{i}.sbs`` for ``count`` shifted crops of one pair."""
    left, right = motorcycle(scale)
    (folder / "L").mkdir(parents=True, exist_ok=True)
    (folder / "S").mkdir(parents=True, exist_ok=True)
    pattern = SamplingPattern(kind="grid", stride_x=stride, stride_y=stride)
    for i in range(count):
        # Different content per frame: roll the rows (both views alike, so disparity is kept).
        write_png(folder / "L" / f"f{i:02d}.png", np.roll(left, i, axis=0))
        save_samples(encode_image(np.roll(right, i, axis=0), pattern=pattern), folder / "S" / f"f{i:02d}.sbs")
    return folder / "L", folder / "S"


def json_lines(text):
    return [json.loads(line) for line in text.splitlines() if line.strip()]


def no_temp_files(*folders):
    return not [p for f in folders if Path(f).exists() for p in Path(f).iterdir() if p.name.endswith(".tmp")]


def invoke_decode(*args):
    return CliRunner().invoke(decode_command, [str(a) for a in args], prog_name="sb-decode")


# =====================================================================================
# Library: inputs, templates, pairs, manifest, up-to-date rule
# =====================================================================================

def test_expand_inputs_files_folders_globs(tmp_path):
    for name in ("b.png", "a.png", "c.tif", "notes.txt", ".hidden.png", "x[1].png"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "d.png").write_bytes(b"x")
    folder = batch.expand_inputs([str(tmp_path)])
    assert [Path(p).name for p in folder] == ["a.png", "b.png", "c.tif", "x[1].png"]
    assert [Path(p).name for p in batch.expand_inputs([str(tmp_path / "*.png")])] == ["a.png", "b.png", "x[1].png"]
    assert [Path(p).name for p in batch.expand_inputs([str(tmp_path / "**" / "d.png")])] == ["d.png"]
    # An existing name with glob characters is taken literally; duplicates are dropped.
    literal = str(tmp_path / "x[1].png")
    assert batch.expand_inputs([literal, literal]) == [literal]
    assert batch.expand_inputs(["-"]) == ["-"]
    assert batch.expand_inputs([str(tmp_path / "missing.png")]) == [str(tmp_path / "missing.png")]
    with pytest.raises(OptionError, match="no file matches"):
        batch.expand_inputs([str(tmp_path / "*.jpg")])
    with pytest.raises(OptionError, match="holds no sample file"):
        batch.expand_inputs([str(tmp_path)], extensions=batch.SAMPLE_EXTENSIONS, what="sample file")


def test_templates_expand_only_known_fields(tmp_path):
    source = "cams/right/frame_007.png"
    assert batch.expand_template("out/{stem}.sbs", source) == "out/frame_007.sbs"
    assert batch.expand_template("{parent}/{name}.sbs", source) == "cams/right/frame_007.png.sbs"
    assert batch.expand_template("x{{stem}}.sbs", source) == "x{stem}.sbs"
    assert batch.has_template("out/{stem}.sbs") and not batch.has_template("out/x{{y}}.sbs")
    # Braces in an input name are never expanded: the input is only a source of values.
    assert batch.expand_template("o/{stem}.sbs", "in/{name}.png") == "o/{name}.sbs"
    for bad in ("out/{stme}.sbs", "out/{stem!r}.sbs", "out/{stem:>5}.sbs", "out/{stem.sbs"):
        with pytest.raises(OptionError):
            batch.expand_template(bad, source)


def test_pair_by_stem_reports_missing_partners():
    pairs = batch.pair_by_stem(["L/a.png", "L/b.png", "L/d.png", "L/d.tif"], ["S/a.sbs", "S/c.sbs", "S/d.sbs"])
    by_stem = {p.stem: p for p in pairs}
    assert by_stem["a"].problem is None and (by_stem["a"].left, by_stem["a"].samples) == ("L/a.png", "S/a.sbs")
    assert "no sample file" in by_stem["b"].problem
    assert "no left image" in by_stem["c"].problem
    assert "several left images" in by_stem["d"].problem


def test_read_manifest(tmp_path):
    manifest = tmp_path / "pairs.csv"
    manifest.write_text("left,samples,max_disp\n# comment\nl/a.png,s/a.sbs,40\n/abs/b.png,s/b.sbs,\n\n")
    pairs = batch.read_manifest(str(manifest))
    assert [(p.left, p.samples, p.max_disp) for p in pairs] == [
        (str(tmp_path / "l/a.png"), str(tmp_path / "s/a.sbs"), 40), ("/abs/b.png", str(tmp_path / "s/b.sbs"), None)]
    manifest.write_text("a.png,a.sbs\n")
    assert [(Path(p.left).name, p.max_disp) for p in batch.read_manifest(str(manifest))] == [("a.png", None)]
    manifest.write_bytes(b"\xef\xbb\xbfleft,samples\na.png,a.sbs\n")        # Excel's "CSV UTF-8"
    assert [Path(p.left).name for p in batch.read_manifest(str(manifest))] == ["a.png"]
    for bad in ("a.png\n", "a.png,a.sbs,many\n", "left,right\nx,y\n", ""):
        manifest.write_text(bad)
        with pytest.raises(OptionError):
            batch.read_manifest(str(manifest))


def test_run_jobs_in_process_and_pool_give_the_same_results(tmp_path):
    _, right = motorcycle(8)
    sources = [write_png(tmp_path / f"r{i}.png", np.roll(right, i, axis=1)) for i in range(4)]
    pattern = SamplingPattern(kind="grid", stride_x=3, stride_y=3)

    def jobs(folder):
        (tmp_path / folder).mkdir()
        return [batch.EncodeJob(source=str(s), output=str(tmp_path / folder / f"{s.stem}.sbs"),
                                pattern=pattern, batch=True) for s in sources]

    seen = []
    serial = list(batch.run_jobs(jobs("a"), batch.encode_job, workers=1, progress=seen.append))
    pooled = list(batch.run_jobs(jobs("b"), batch.encode_job, workers=2))
    assert [r["status"] for r in serial] == ["ok"] * 4 and seen == serial
    assert sorted(r["status"] for r in pooled) == ["ok"] * 4
    for s in sources:
        assert (tmp_path / "a" / f"{s.stem}.sbs").read_bytes() == (tmp_path / "b" / f"{s.stem}.sbs").read_bytes()


# =====================================================================================
# sb-encode batches
# =====================================================================================

def test_encode_batch_with_two_jobs_skips_and_redoes_like_make(tmp_path):
    _, right = motorcycle(8)
    (tmp_path / "cam_r").mkdir()
    for i in range(5):
        write_png(tmp_path / "cam_r" / f"f{i}.png", np.roll(right, i, axis=1))
    args = [SB_ENCODE, "cam_r/*.png", "-o", "out/{stem}.sbs", "--stride", "4", "-j", "2", "--json"]
    first = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert first.returncode == 0, first.stderr
    assert first.stderr == ""               # no progress bar when stderr is not a terminal
    lines = json_lines(first.stdout)
    assert sorted(r["input"] for r in lines) == [f"cam_r/f{i}.png" for i in range(5)]
    assert {r["status"] for r in lines} == {"ok"}
    assert all(r["epsilon"] == pytest.approx(load_samples(tmp_path / r["output"]).epsilon) for r in lines)
    assert all(r["output"] == f"out/{Path(r['input']).stem}.sbs" for r in lines)

    # Rerun: everything up to date.  Then one input changes: only it is redone.
    # (Hidden files are the records of what made each output.)
    mtimes = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out").iterdir() if not p.name.startswith(".")}
    time.sleep(0.02)
    os.utime(tmp_path / "cam_r" / "f3.png")
    second = subprocess.run(args, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert second.returncode == 0, second.stderr
    status = {Path(r["input"]).stem: r["status"] for r in json_lines(second.stdout)}
    assert status == {"f0": "skipped", "f1": "skipped", "f2": "skipped", "f3": "ok", "f4": "skipped"}
    after = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "out").iterdir() if not p.name.startswith(".")}
    assert all(after[n] == mtimes[n] for n in mtimes if n != "f3.sbs") and after["f3.sbs"] > mtimes["f3.sbs"]


def test_encode_several_inputs_need_a_template(tmp_path):
    _, right = motorcycle(8)
    a, b = write_png(tmp_path / "a.png", right), write_png(tmp_path / "b.png", right)
    proc = subprocess.run([SB_ENCODE, a, b, "-o", tmp_path / "x.sbs"], capture_output=True, text=True)
    assert proc.returncode == OptionError.exit_code and "has no template" in proc.stderr
    proc = subprocess.run([SB_ENCODE, str(tmp_path / "*.jpg"), "-o", "{stem}.sbs"], capture_output=True, text=True)
    assert proc.returncode == OptionError.exit_code and "no file matches" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_encode_broken_pipe_is_quiet(tmp_path):
    left, _ = motorcycle(2)                 # 370x250 RGB at stride 1: ~280 kB, more than a pipe holds
    image = write_png(tmp_path / "big.png", left)
    proc = subprocess.run(f"'{SB_ENCODE}' '{image}' --stride 1 -o - | head -c 10 > /dev/null; "
                          "echo ${PIPESTATUS[0]} >&2", shell=True, executable="/bin/bash",
                          capture_output=True, text=True, timeout=60)
    lines = proc.stderr.splitlines()
    assert "Traceback" not in proc.stderr and "Error" not in proc.stderr
    assert lines == ["141"]                 # 128 + SIGPIPE, nothing else on stderr


# =====================================================================================
# sb-decode batches
# =====================================================================================

def test_decode_batch_corrupt_input_and_missing_pair(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 3)
    cut = samples_dir / "f01.sbs"
    cut.write_bytes(cut.read_bytes()[:50])          # a transfer that stopped inside the header
    write_png(left_dir / "lonely.png", motorcycle(8)[0])
    save_samples(load_samples(samples_dir / "f00.sbs"), samples_dir / "orphan.sbs")
    result = invoke_decode("--left-dir", left_dir, "--samples-dir", samples_dir, "--max-disp", MAX_DISP,
                           "--disparity", tmp_path / "D" / "{stem}.pfm", "-j", "1", "--json")
    assert result.exit_code == 1, result.stderr
    by_stem = {Path(r["left"] or r["samples"]).stem: r for r in json_lines(result.stdout)}
    assert set(by_stem) == {"f00", "f01", "f02", "lonely", "orphan"}
    assert by_stem["f00"]["status"] == by_stem["f02"]["status"] == "ok"
    assert by_stem["f01"]["status"] == "failed" and by_stem["f01"]["error_class"] == "TruncatedFileError"
    assert "f01.sbs" in by_stem["f01"]["error"] and by_stem["f01"]["exit_code"] == 5
    assert by_stem["lonely"]["status"] == "failed" and "no sample file" in by_stem["lonely"]["error"]
    assert by_stem["orphan"]["status"] == "failed" and "no left image" in by_stem["orphan"]["error"]
    assert sorted(p.name for p in (tmp_path / "D").iterdir() if not p.name.startswith(".")) == ["f00.pfm", "f02.pfm"]
    # One stderr line per failed pair, plus the count.
    errors = [line for line in result.stderr.splitlines() if line.startswith("sb-decode: error: ")]
    assert len(errors) == 3 and "3 of 5" in result.stderr and "Traceback" not in result.stderr


def test_decode_manifest_and_template_rules(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 2)
    manifest = tmp_path / "pairs.csv"
    manifest.write_text("left,samples,max_disp\nL/f00.png,S/f00.sbs,10\nL/f01.png,S/f01.sbs,12\n")
    result = invoke_decode("--manifest", manifest, "--disparity", tmp_path / "out.pfm")
    assert result.exit_code == OptionError.exit_code and "has no template" in result.stderr
    result = invoke_decode("--manifest", manifest, "--disparity", tmp_path / "D" / "{stem}.npy",
                           "--preview", tmp_path / "P" / "{name}", "-j", "1", "--json")
    assert result.exit_code == 0, result.stderr
    lines = {Path(r["left"]).stem: r for r in json_lines(result.stdout)}
    assert lines["f00"]["max_disp"] == 10 and lines["f01"]["max_disp"] == 12
    assert np.load(tmp_path / "D" / "f00.npy").shape == cv2.imread(str(left_dir / "f00.png")).shape[:2]
    assert (tmp_path / "P" / "f01.png").exists()
    # Two pairs writing one file is refused before any work.
    result = invoke_decode("--manifest", manifest, "--disparity", tmp_path / "{parent}.pfm")
    assert result.exit_code == OptionError.exit_code and "same output" in result.stderr


def test_decode_batch_two_jobs_matches_single_runs(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 4)
    proc = subprocess.run([SB_DECODE, "--left-dir", left_dir, "--samples-dir", samples_dir, "--max-disp",
                           str(MAX_DISP), "--disparity", str(tmp_path / "D" / "{stem}.pfm"), "-j", "2", "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = json_lines(proc.stdout)
    assert sorted(r["status"] for r in lines) == ["ok"] * 4
    # The pool's results equal an in-process decode of the same pair.
    single = invoke_decode(left_dir / "f02.png", samples_dir / "f02.sbs", "--max-disp", MAX_DISP,
                           "--disparity", tmp_path / "single.pfm")
    assert single.exit_code == 0, single.stderr
    np.testing.assert_allclose(read_disparity(tmp_path / "D" / "f02.pfm"), read_disparity(tmp_path / "single.pfm"),
                               atol=1e-4)


def test_decode_on_dask_local_cluster(tmp_path):
    pytest.importorskip("distributed")
    left_dir, samples_dir = make_pairs(tmp_path, 3)
    proc = subprocess.run([SB_DECODE, "--left-dir", left_dir, "--samples-dir", samples_dir, "--max-disp",
                           str(MAX_DISP), "--disparity", str(tmp_path / "D" / "{stem}.tif"),
                           "--scheduler", "local", "-j", "2", "--json"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = json_lines(proc.stdout)
    assert sorted(Path(r["left"]).stem for r in lines) == ["f00", "f01", "f02"]
    assert {r["status"] for r in lines} == {"ok"}
    assert all(read_disparity(tmp_path / "D" / f"f0{i}.tif").shape == (62, 92) for i in range(3))


def test_run_jobs_on_a_threaded_dask_client(tmp_path):
    distributed = pytest.importorskip("distributed")
    left_dir, samples_dir = make_pairs(tmp_path, 2)
    jobs = [batch.DecodeJob(left=str(left_dir / f"f0{i}.png"), samples=str(samples_dir / f"f0{i}.sbs"),
                            disparity=str(tmp_path / f"d{i}.npy"), max_disp=MAX_DISP, batch=True)
            for i in range(2)]
    jobs.append(batch.DecodeJob(left=str(left_dir / "f00.png"), samples=str(left_dir / "f01.png"),
                                disparity=str(tmp_path / "bad.npy"), max_disp=MAX_DISP, batch=True))
    from stereobudget._kernels import _scratch as scratch
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        results = list(batch.run_jobs(jobs, batch.decode_job, scheduler=client))
        # The client's workers outlive the batch: the volumes its decodes kept for a next
        # frame are handed back (these workers are threads of this process).
        assert scratch.spare_bytes() == 0
    assert sorted(r["status"] for r in results) == ["failed", "ok", "ok"]
    failed = next(r for r in results if r["status"] == "failed")
    assert failed["error_class"] == "NotASampleFileError" and failed["exit_code"] == NotASampleFileError.exit_code
    assert (tmp_path / "d0.npy").exists() and (tmp_path / "d1.npy").exists() and not (tmp_path / "bad.npy").exists()


def test_missing_dask_is_a_clear_error(tmp_path, monkeypatch):
    left_dir, samples_dir = make_pairs(tmp_path, 2)
    monkeypatch.setitem(sys.modules, "distributed", None)
    result = invoke_decode("--left-dir", left_dir, "--samples-dir", samples_dir, "--max-disp", MAX_DISP,
                           "--disparity", tmp_path / "{stem}.pfm", "--scheduler", "local")
    assert result.exit_code == OptionError.exit_code and "dask" in result.stderr
    assert "Traceback" not in result.stderr


def test_killed_batch_resumes_without_redoing_finished_files(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 16, scale=4, stride=5)
    out = tmp_path / "D"
    args = [SB_DECODE, "--left-dir", str(left_dir), "--samples-dir", str(samples_dir), "--max-disp", "20",
            "--disparity", str(out / "{stem}.pfm"), "--right", str(out / "{stem}.png"), "-j", "2", "--json"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out.exists() and any(out.glob("*.png"))):
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr, stderr
    assert no_temp_files(out), sorted(p.name for p in out.iterdir())
    finished = {p.stem for p in out.glob("*.png")} & {p.stem for p in out.glob("*.pfm")}
    assert 1 <= len(finished) < 16, ("the batch should have been killed part-way", sorted(finished), stderr)
    mtimes = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}

    rerun = subprocess.run(args, capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    status = {Path(r["left"]).stem: r["status"] for r in json_lines(rerun.stdout)}
    assert len(status) == 16
    assert {s for s, st in status.items() if st == "skipped"} == finished, (status, finished, stderr)
    assert all(st == "ok" for s, st in status.items() if s not in finished)
    for name, mtime in mtimes.items():
        if Path(name).stem in finished:
            assert (out / name).stat().st_mtime_ns == mtime
    assert no_temp_files(out) and len(list(out.glob("*.pfm"))) == 16


def test_decode_batch_json_into_closed_pipe_is_quiet(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 3)
    cmd = (f"'{SB_DECODE}' --left-dir '{left_dir}' --samples-dir '{samples_dir}' --max-disp {MAX_DISP} "
           f"--disparity '{tmp_path}/D/{{stem}}.pfm' -j 1 --json | head -n 0")
    proc = subprocess.run(cmd, shell=True, executable="/bin/bash", capture_output=True, text=True, timeout=600)
    # On a fresh install the first decode says that it compiles; nothing else may be said.
    said = [line for line in proc.stderr.splitlines() if "compiling kernels, first run only" not in line]
    assert said == [] and proc.returncode == 0
    assert no_temp_files(tmp_path / "D")


def test_progress_bar_only_on_a_terminal(tmp_path):
    import pty
    _, right = motorcycle(8)
    (tmp_path / "in").mkdir()
    for i in range(3):
        write_png(tmp_path / "in" / f"f{i}.png", right)

    def stderr_on_a_terminal(*extra):
        master, slave = pty.openpty()
        proc = subprocess.Popen([SB_ENCODE, "in", "-o", "out/{stem}.sbs", "-j", "1", "--overwrite", *extra],
                                cwd=tmp_path, stdout=subprocess.PIPE, stderr=slave)
        os.close(slave)
        chunks = []
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:          # EIO: the child closed the terminal
                break
            if not chunk:
                break
            chunks.append(chunk)
        os.close(master)
        assert proc.wait(timeout=60) == 0
        return b"".join(chunks).decode(errors="replace")

    shown = stderr_on_a_terminal()
    assert "100%" in shown and "sb-encode" in shown
    assert stderr_on_a_terminal("-q") == ""


def test_a_change_of_how_the_right_image_is_made_redoes_it(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 1)
    args = ["--left-dir", left_dir, "--samples-dir", samples_dir, "--max-disp", MAX_DISP,
            "--right", tmp_path / "R" / "{stem}.png", "--json"]
    first = invoke_decode(*args)
    assert first.exit_code == 0, first.stderr
    again = invoke_decode(*args)
    assert [r["status"] for r in json_lines(again.stdout)] == ["skipped"]
    plain = invoke_decode(*args, "--no-enhance")
    assert plain.exit_code == 0, plain.stderr
    (result,) = json_lines(plain.stdout)
    assert result["status"] == "ok" and "synthesis.enhance" in result["redone"]
    unwarped = invoke_decode(*args, "--warp", "nearest")
    (result,) = json_lines(unwarped.stdout)
    assert result["status"] == "ok" and "synthesis.warp_mode" in result["redone"]


def test_synthesis_options_need_the_right_image(tmp_path):
    left_dir, samples_dir = make_pairs(tmp_path, 1)
    result = invoke_decode(left_dir / "f00.png", samples_dir / "f00.sbs", "--max-disp", MAX_DISP,
                           "--disparity", tmp_path / "d.pfm", "--no-enhance")
    assert result.exit_code == OptionError.exit_code and "--right" in result.stderr


def test_two_outputs_of_one_pair_on_one_file_are_told_apart_from_two_pairs():
    from types import SimpleNamespace
    same = [SimpleNamespace(label="L/a.png", outputs=["D/a.pfm", "D/a.pfm"])]
    with pytest.raises(OptionError, match="two outputs of L/a.png are the same file 'D/a.pfm'"):
        batch.check_distinct_outputs(same, key=lambda job: job.outputs)
    clash = [SimpleNamespace(label=f"L{i}/a.png", outputs=["D/a.pfm"]) for i in range(2)]
    with pytest.raises(OptionError, match=r"two inputs would write the same output 'D/a.pfm' \(L0/a.png and L1/a.png\)"):
        batch.check_distinct_outputs(clash, key=lambda job: job.outputs)

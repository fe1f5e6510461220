"""The command line: commands run, and bad input is one line on stderr with status 2."""

import json
import os
import platform
import subprocess
import sys

import numpy as np
import pytest
from helpers import command_error

from ctjax import CtjaxError
from ctjax.cli import main
from ctjax.io import load_capture


def test_synth_command_writes_a_capture(tmp_path, capsys):
    out = tmp_path / "cap"
    status = main(
        [
            "synth",
            str(out),
            "--frames",
            "2",
            "--width",
            "64",
            "--height",
            "48",
            "--seed",
            "7",
            "--light-offset",
            "5",
            "0",
            "0",
            "--inverse-square",
        ]
    )
    assert status == 0
    capture = load_capture(out)
    assert len(capture) == 2 and capture.truth["seed"] == 7
    assert set(capture.truth["effects"]) == {"light_offset", "inverse_square"}
    assert "wrote synthetic capture" in capsys.readouterr().out


@pytest.mark.slow
def test_demo_command_runs_the_whole_pipeline_from_images(tmp_path):
    """synth -> reconstruct -> masks -> fit -> calibrate-light -> evaluate, from images alone
    (a small, strongly textured capture so that SfM has features at this size)."""
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--frames", "4", "--width", "192", "--height", "160"]
    # The near light without falloff (the falloffs and the choice among them are
    # test_calibration's): 8.5 -> 5.9 s of the demo's 36 here.
    argv += ["--falloff", "none"]
    assert main([*argv, "--texture-contrast", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["reconstruction"]["registered"] == [f"frame_{i:03d}" for i in range(4)]
    assert summary["sfm_normal_error_deg"][0] < 3.0
    assert set(summary["brdf_fit"]) >= {"rho_tilde", "F_tilde", "sigma", "rgb_rmse"}
    assert all(np.isfinite(summary["brdf_fit"]["rho_tilde"])) and summary["brdf_fit"]["sigma"] > 0
    evaluation = summary["evaluation"]
    for model in ("lambertian", "cook_torrance"):
        for key in ("rgb_rmse_calibration", "rgb_rmse_test", "sfs_error_mm"):
            assert np.isfinite(evaluation[f"{model}_{key}"])
    assert evaluation["cook_torrance_rgb_rmse_test"] < evaluation["lambertian_rgb_rmse_test"]
    assert evaluation["albedo"] == "map"
    assert any("one albedo per model" in note for note in evaluation["notes"])
    assert set(summary["timings_s"]) >= {"reconstruct", "fit", "evaluate", "total"}
    page = (out / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 5 and "Cook-Torrance" in page
    # Each estimate's status is in the summary and the report (a synthetic lobe: measured).
    assert summary["brdf_fit"]["status"] == "successful" and "<td>status</td>" in page


def test_bad_input_is_one_line_and_status_2(tmp_path):
    """From the console (a process of its own: the exit status, nothing after the line)."""
    argv = ["synth", str(tmp_path / "c"), "--sigma", "-1"]
    result = subprocess.run(
        [sys.executable, "-m", "ctjax.cli", *argv], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "sigma" in lines[0] and "Traceback" not in result.stderr


@pytest.mark.parametrize(
    "argv, message",
    [
        (["synth", "{tmp}/c", "--frames", "0"], "frames"),
        (["synth", "{tmp}/c", "--ambient", "0.1", "0.2"], "1 or 3 values"),
    ],
)
def test_bad_input_is_one_line_and_status_2_in_process(tmp_path, capsys, argv, message):
    status, lines = command_error([a.replace("{tmp}", str(tmp_path)) for a in argv], capsys)
    assert status == 2 and len(lines) == 1 and message in lines[0]


def test_the_compilation_cache_folder_is_documented_and_overridable(monkeypatch, tmp_path):
    from ctjax._performance import compilation_cache_dir

    monkeypatch.delenv("CTJAX_NO_CACHE", raising=False)
    monkeypatch.setenv("CTJAX_CACHE_DIR", str(tmp_path / "c"))
    assert compilation_cache_dir() == tmp_path / "c"
    monkeypatch.delenv("CTJAX_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert compilation_cache_dir() == tmp_path / "x" / "ctjax" / "jax"
    monkeypatch.setenv("CTJAX_NO_CACHE", "1")
    assert compilation_cache_dir() is None


def test_console_command_exits_with_the_status_after_atexit_and_flushed_output(tmp_path):
    """`ctjax` (`cli.run`) skips the interpreter's finalisation, but not the atexit
    handlers, the exit status or what was printed."""
    code = (
        "import atexit, sys; atexit.register(lambda: print('atexit ran')); "
        f"sys.argv = ['ctjax', 'fit', {str(tmp_path / 'missing')!r}, '--json', 'f.json']; "
        "from ctjax.cli import run; run()"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 2
    assert "capture folder not found" in result.stderr
    assert result.stdout.strip() == "atexit ran"


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="glibc's mallopt only")
def test_malloc_tuning_is_applied_before_the_first_computation():
    """`tune_malloc` (the thresholds and one arena) succeeds in a fresh process, before
    JAX's threads exist; in a subprocess, so that the test session keeps glibc's defaults."""
    code = "import ctjax; print(ctjax.tune_malloc())"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0 and result.stdout.strip() == "True", result.stderr


@pytest.mark.slow
def test_xla_tuning_adds_the_vector_width_once_and_keeps_the_users():
    """`tune_xla` adds 512-bit vectors to XLA_FLAGS on an AVX-512 CPU (and nothing
    elsewhere), keeps a width the user set, and does nothing once the backend runs."""
    from ctjax._performance import _has_avx512

    code = (
        "import os, jax, ctjax; first = ctjax.tune_xla(); flags = os.environ.get('XLA_FLAGS', '');"
        "jax.numpy.zeros(1).block_until_ready(); ctjax.tune_xla.cache_clear();"
        "print(first, repr(flags), ctjax.tune_xla())"
    )
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert result.returncode == 0, result.stderr
    wide = _has_avx512()
    expected = "'--xla_cpu_prefer_vector_width=512'" if wide else "''"
    assert result.stdout.split() == [str(wide), expected, "False"]
    env["XLA_FLAGS"] = "--xla_cpu_prefer_vector_width=256"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert result.stdout.split() == ["False", "'--xla_cpu_prefer_vector_width=256'", "False"]


def test_demo_refuses_an_unknown_falloff_before_any_work(tmp_path):
    from ctjax.demo import run_demo

    with pytest.raises(CtjaxError, match=r"falloff must be one of auto, none, .*got 'spots'"):
        run_demo(tmp_path / "demo", falloff="spots")
    assert not (tmp_path / "demo").exists()


# Every command's outputs: a file argument that is a folder, a folder argument that is a
# file, and a path under a file; `{file}` and `{dir}` exist, `{cap}` need not (the paths
# are checked when the command line is parsed, before the capture is read).
OUTPUT_CASES = [
    (["fit", "{cap}", "--json", "{dir}"], "--json: {dir}: is a directory"),
    (["fit", "{cap}", "--json", "{file}/f.json"], "--json: {file}/f.json: {file} is not a folder"),
    (["fit", "{cap}", "--json", "f.json", "--albedo-maps", "{file}"], "exists and is not a folder"),
    (["masks", "{cap}", "--out", "{file}"], "--out: {file}: exists and is not a folder"),
    (["diagnose", "{cap}", "--json", "d.json", "--plots", "{file}"], "--plots: {file}: exists"),
    (["evaluate", "{cap}", "--json", "e.json", "--plots", "{file}"], "--plots: {file}: exists"),
    (["evaluate", "{cap}", "--json", "{dir}"], "--json: {dir}: is a directory"),
    (["calibrate-light", "{cap}", "--json", "c.json", "--npz", "{dir}"], "--npz: {dir}: is a"),
    (["reconstruct", "{cap}", "--json", "{dir}"], "--json: {dir}: is a directory"),
    (["reconstruct", "{cap}", "--out", "{file}"], "--out: {file}: exists and is not a folder"),
    (["import", "v.mp4", "--camera", "c.json", "--out", "{file}"], "--out: {file}: exists"),
    (["import", "v.mp4", "--camera", "c.json", "--out", "o", "--json", "{dir}"], "is a directory"),
    (["synth", "{file}"], "argument out: {file}: exists and is not a folder"),
    (["demo", "--out", "{file}/demo"], "--out: {file}/demo: {file} is not a folder"),
    (["batch", "{cap}", "--out", "{file}"], "--out: {file}: exists and is not a folder"),
]


@pytest.mark.parametrize("argv, message", OUTPUT_CASES, ids=[" ".join(c[0]) for c in OUTPUT_CASES])
def test_output_paths_of_the_wrong_kind_are_refused_before_any_work(
    tmp_path, capsys, argv, message
):
    paths = {"{file}": tmp_path / "afile", "{dir}": tmp_path / "adir", "{cap}": tmp_path / "cap"}
    paths["{file}"].write_text("kept")
    paths["{dir}"].mkdir()

    def filled(text):
        for key, path in paths.items():
            text = text.replace(key, str(path))
        return text

    capsys.readouterr()
    assert main([filled(a) for a in argv]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ctjax {argv[0]}: error: "), lines
    assert filled(message) in lines[0]
    assert paths["{file}"].read_text() == "kept" and not any(paths["{dir}"].iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "afile"]


def test_atomic_writes_name_a_folder_in_the_way(tmp_path):
    """The Python API's writers: one `CtjaxError` naming the path, not an OSError."""
    from ctjax.io._atomic import atomic_write_json, atomic_write_npy

    (tmp_path / "afile").write_text("kept")
    with pytest.raises(CtjaxError, match="is a directory"):
        atomic_write_json(tmp_path, {})
    with pytest.raises(CtjaxError, match=r"afile is not a folder"):
        atomic_write_npy(tmp_path / "afile" / "a.npy", np.zeros(2))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_the_knee_is_fitted_by_default_where_the_frames_show_one(capsys):
    """`--effects` not given: the knee `load_capture` found, in its channels only (with a
    note), else none; given, as given (`none`: none, and not beside others)."""
    import argparse
    import types

    from ctjax._commands._args import chosen_effects
    from ctjax.effects import Knee
    from ctjax.io._channel_ceiling import ChannelKnee

    kneed = types.SimpleNamespace(knees=(ChannelKnee(0, 162.0, 1.68, 0.53, 255),), encoding="srgb")
    linear = types.SimpleNamespace(knees=(), encoding="srgb")

    def args(effects):
        return argparse.Namespace(effects=effects, command="evaluate")

    (knee,) = chosen_effects(args(None), kneed)
    assert isinstance(knee, Knee) and knee.compressed == (True, False, False)
    assert "the camera's knee in R (the note above) is fitted" in capsys.readouterr().err
    assert chosen_effects(args(None), linear) == ()
    assert chosen_effects(args(["none"]), kneed) == ()
    assert chosen_effects(args(["frame_exposure"]), kneed) == ("frame_exposure",)
    assert capsys.readouterr().err == ""
    with pytest.raises(CtjaxError, match="--effects none fits no effects"):
        chosen_effects(args(["none", "knee"]), kneed)

"""`ctjax batch`: many captures, one result folder each, a summary row each; a failed
capture is reported and the others kept; a rerun skips what is done."""

import csv
import json

import pytest

from ctjax.batch import run_batch
from ctjax.cli import main
from ctjax.synth import SynthOptions, synthesize


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    options = SynthOptions(width=64, height=48, frames=2, texture=False)
    good = synthesize(root / "good", options)
    broken = root / "broken"
    broken.mkdir()  # no camera.json
    return good, broken


def _rows(out):
    with open(out / "summary.csv") as handle:
        return {row["capture"]: row for row in csv.DictReader(handle)}


def test_a_failed_capture_is_reported_and_the_others_kept(captures, tmp_path, capsys):
    good, broken = captures
    out = tmp_path / "out"
    argv = ["batch", str(good), str(broken), "--out", str(out), "--steps", "fit"]
    assert main([*argv, "--workers", "0"]) == 1
    rows = _rows(out)
    assert rows["good"]["status"] == "ok" and float(rows["good"]["sigma"]) > 0
    assert len(rows["good"]["F_tilde"].split()) == 3 and rows["good"]["length_unit"] == "mm"
    # The fit's own status (a measured lobe on this synthetic capture) beside its figures.
    fit = json.loads((out / "good" / "fit.json").read_text())
    assert rows["good"]["fit_status"] == fit["status"] != ""
    assert rows["good"]["fit_exposure"] == fit["exposure"]["fitted"] == "one"
    assert (
        rows["broken"]["status"] == "failed" and "camera.json not found" in rows["broken"]["error"]
    )
    assert (out / "good" / "fit.json").is_file() and (out / "good" / "done.json").is_file()
    assert "2 capture(s), 1 failed" in (out / "summary.html").read_text()
    assert "failed: broken" in capsys.readouterr().err
    # A rerun skips the capture already done, and tries the failed one again.
    messages = []
    run_batch([good, broken], out, ["fit"], workers=0, progress=messages.append)
    assert messages[0] == "1 capture(s) already done (skipped)"
    assert len(messages) == 2 and "broken failed" in messages[1]


def test_the_effects_reach_the_steps_that_fit_them(captures, tmp_path):
    good, _ = captures
    rows = run_batch([good], tmp_path / "out", ["fit"], workers=0, effects=["frame_exposure"])
    assert rows[0]["status"] == "ok", rows[0]["error"]
    fit = json.loads((tmp_path / "out" / "good" / "fit.json").read_text())
    assert len(fit["log_exposure"]) == 1 and abs(fit["log_exposure"][0]) < 0.01  # none here


@pytest.mark.slow
def test_captures_run_on_dask_workers(captures, tmp_path):
    good, _ = captures
    rows = run_batch([good], tmp_path / "out", ["fit"], workers=1)
    assert rows[0]["status"] == "ok", rows[0]["error"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--steps", "fit,paint"], "unknown step(s) paint"),
        (["--workers", "-1"], "--workers"),
        (["--steps", " , "], "no step given"),
        (["--steps", "fit", "--scheduler", "notanaddress"], "Dask scheduler at notanaddress"),
        (["{missing}", "--steps", "fit"], "not a capture folder: {missing}"),
        (["--steps", "fit", "--effects", "vignetting"], "fit takes frame_exposure only"),
        (["--effects", "glare"], "glare: not image effects"),
        (["--steps", "diagnose", "--effects", "frame_exposure"], "--effects is for the steps"),
    ],
)
def test_bad_batch_options_are_one_line(captures, tmp_path, capsys, extra, message):
    good, _ = captures
    missing = str(tmp_path / "no-such-capture")
    extra = [word.format(missing=missing) for word in extra]
    given = [str(good), *extra[:1]] if extra[0] == missing else [str(good)]
    extra = extra[1:] if extra[0] == missing else extra
    assert main(["batch", *given, "--out", str(tmp_path / "o"), *extra]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message.format(missing=missing) in lines[0], lines
    assert not (tmp_path / "o" / good.name).exists()  # refused before any work


def test_captures_of_one_name_are_refused_and_links_keep_their_names(tmp_path, capsys):
    """Two captures named alike (`SEQUENCE/reconstructed`, as benchmarks/real_video.py
    writes them) would share a result folder: refused in one line; given as links of
    distinct names, each link's name is its result folder's."""
    from ctjax.batch import _jobs

    folders = [tmp_path / sequence / "reconstructed" for sequence in ("sinus", "chole")]
    for folder in folders:
        folder.mkdir(parents=True)
    out = tmp_path / "o"
    assert main(["batch", *map(str, folders), "--out", str(out), "--steps", "fit"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "same folder name (reconstructed)" in line and "links of distinct names" in line
    links = []
    for folder in folders:
        links.append(tmp_path / "links" / folder.parent.name)
        links[-1].parent.mkdir(exist_ok=True)
        links[-1].symlink_to(folder, target_is_directory=True)
    jobs = _jobs(links, out, ("fit",))
    assert [job.name for job in jobs] == ["sinus", "chole"]
    assert [job.folder for job in jobs] == [out.resolve() / "sinus", out.resolve() / "chole"]
    assert [job.capture.resolve() for job in jobs] == [f.resolve() for f in folders]


def test_without_dask_one_line_names_the_extra_and_exit_2(captures, tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if not installed
    good, _ = captures
    status = main(["batch", str(good), "--out", str(tmp_path / "out"), "--workers", "2"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1, lines
    assert lines[0].startswith("ctjax batch: error: ") and "pip install 'ctjax[batch]'" in lines[0]
    assert "--workers 0" in lines[0] and not (tmp_path / "out" / good.name).exists()

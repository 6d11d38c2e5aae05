"""The run folder as a transaction (issue 19): output paths checked before any work, a staging folder moved
into place whole, an earlier run replaced only with --overwrite and never damaged by a run that fails, the
failed run's log kept with the stage and the error, metrics.json strict JSON."""

import json
import math
import os

import numpy as np
import pytest
import yaml
from capture.test_photometric_stereo import make_folder
from report.test_run_result import write_run

from torchrefl.errors import OutputError
from torchrefl.report.metrics import strict_json
from torchrefl.report.run_folder import StagedRunFolder, output_folder
from torchrefl.report.run_marker import write_marker
from torchrefl.report.run_result import load_run
from torchrefl.train import main


def test_output_paths_that_cannot_be_a_folder_are_named_errors(tmp_path, monkeypatch):
    for raw in ("", "   "):
        with pytest.raises(OutputError, match="output.dir is empty"):
            output_folder(raw)
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="is a file, expected a folder"):
        output_folder(str(tmp_path / "file"))
    with pytest.raises(OutputError, match="file.*is a file, so .* cannot be created"):
        output_folder(str(tmp_path / "file" / "sub" / "run"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("RUNS", str(tmp_path / "runs"))
    assert output_folder("~/runs/x") == tmp_path / "home" / "runs" / "x"
    assert output_folder("$RUNS/x") == tmp_path / "runs" / "x"
    monkeypatch.delenv("NO_SUCH_VARIABLE_19", raising=False)
    with pytest.raises(OutputError, match="unset environment variable"):
        output_folder("$NO_SUCH_VARIABLE_19/x")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes anywhere")
def test_an_output_folder_without_write_permission_is_refused(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="no permission"):
            output_folder(str(locked / "run"))
    finally:
        locked.chmod(0o700)


def test_cli_refuses_bad_output_paths_before_any_work(tmp_path, capsys, monkeypatch):
    """output.dir= (empty) once wrote into the current folder and replaced its config.yaml; a file as the
    output folder or as its parent ended in tracebacks."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "config.yaml").write_text("seed: 3\n")
    (tmp_path / "afile").write_text("x")
    for value, fragment in (
        ("", "output.dir is empty"),
        (str(tmp_path / "afile"), "is a file"),
        (str(tmp_path / "afile" / "run"), "is a file, so"),
    ):
        assert main([str(tmp_path / "config.yaml"), f"output.dir={value}", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert fragment in err and "Traceback" not in err
    assert (tmp_path / "config.yaml").read_text() == "seed: 3\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "config.yaml"]


def test_a_folder_holding_other_files_or_a_run_is_refused(tmp_path):
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    for overwrite in (False, True):
        with pytest.raises(OutputError, match="not a torchrefl run"):
            StagedRunFolder(other, overwrite)
    assert (other / "notes.txt").read_text() == "mine"
    write_run(tmp_path / "run")
    with pytest.raises(OutputError, match="holds an earlier run; give --overwrite"):
        StagedRunFolder(tmp_path / "run")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other", "run"]  # no staging folder left behind


def test_commit_replaces_an_earlier_run_whole(tmp_path):
    """A new run into a folder holding another left the old capture/, selection/ and maps/light_NNN_* beside
    the new results; now the new run takes the folder's place as a whole."""
    old = tmp_path / "run"
    write_run(old)
    (old / "maps").mkdir()
    (old / "maps" / "light_005_diff.png").write_bytes(b"old")
    write_marker(old)
    staged = StagedRunFolder(old, overwrite=True)
    assert staged.path.parent == tmp_path and staged.path.name.startswith(".run.staging-")
    assert load_run(old).metrics["lights"] == 3  # the earlier run is whole until the commit
    write_run(staged.path, seed=7)
    (staged.path / "run_complete.json").unlink()
    staged.commit()
    assert not (old / "maps").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    run = load_run(old)
    np.testing.assert_array_equal(run.pd, np.load(old / "params.npz")["pd"])


def test_overwrite_never_deletes_a_users_files_but_os_metadata_goes_with_the_run(tmp_path, capsys):
    """Issue 33: --overwrite replaced a finished run folder whole, deleting the figure a user had saved in it.
    Now such a folder is refused before any work, naming the file; a .DS_Store alone does not stop the run."""
    run = tmp_path / "run"
    write_run(run)
    (run / "figure.png").write_bytes(b"my figure")
    (run / ".DS_Store").write_bytes(b"Bud1")
    for overwrite in (False, True):
        with pytest.raises(OutputError, match=r"1 file\(s\) it did not write \(e\.g\. \['figure\.png'\]\).*move them"):
            StagedRunFolder(run, overwrite)
    argv = tiny_capture_args(tmp_path, f"output.dir={run}", "--overwrite", "--quiet")
    assert main(argv) == 2
    assert "figure.png" in capsys.readouterr().err
    assert (run / "figure.png").read_bytes() == b"my figure"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ps", "ps.yaml", "run"]  # no staging or failed folder
    (run / "figure.png").unlink()
    assert main(argv) == 0
    assert not (run / ".DS_Store").exists() and load_run(run).unrecorded == ()


def test_a_stale_staging_folder_of_a_killed_run_is_removed(tmp_path):
    stale = tmp_path / ".run.staging-999999999"
    stale.mkdir()
    (stale / "params.npz").write_bytes(b"half")
    staged = StagedRunFolder(tmp_path / "run")
    assert not stale.exists() and staged.path.is_dir()


def tiny_capture_args(tmp_path, *extra):
    """main() arguments for a run on an 8 x 6, 4-light photometric stereo folder (a run takes a fraction of a
    second: no refinement)."""
    make_folder(tmp_path / "ps")
    cfg = tmp_path / "ps.yaml"
    cfg.write_text(
        yaml.safe_dump({"capture": {"kind": "photometric_stereo", "path": "ps"}, "fit": {"optimizer": "none"}})
    )
    return [str(cfg), *extra]


def test_a_failing_run_leaves_the_earlier_run_whole_and_logs_the_error(tmp_path, capsys):
    """A failing run replaced config.yaml and log.txt and left the old params.npz: load_run then returned
    one run's parameters with another's config. Now the target is untouched and the failed run's files are in
    NAME.failed, its log naming the stage and the error; no failed stage is logged as done."""
    run = tmp_path / "run"
    params = write_run(run)
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    # the capture is read (work done), then fit.holdout names a light the capture does not have
    argv = tiny_capture_args(tmp_path, f"output.dir={run}", "fit.holdout=[99]", "--overwrite", "--quiet")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("fit.holdout") == 1 and f"files and log are in {tmp_path / 'run.failed'}" in err
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    np.testing.assert_array_equal(load_run(run).pd, params["pd"])
    log = (tmp_path / "run.failed" / "log.txt").read_text()
    assert "[capture] done" in log and "[precompute] failed after" in log and "[precompute] done" not in log
    assert "error in stage 'precompute'" in log and "fit.holdout" in log
    assert not any(p.name.startswith(".run.staging") for p in tmp_path.iterdir())


@pytest.mark.parametrize(
    "override, message",
    [
        ("fit.optimiser=lm", "unknown key 'fit.optimiser'"),  # a bad key: refused by the config loader
        ("capture.path=nowhere", "nowhere"),  # a missing capture folder: refused by the capture stage
        ("output.dir=", "output.dir is empty"),  # a bad output.dir: refused before the staging folder
    ],
)
def test_an_error_found_before_any_work_leaves_nothing_and_is_printed_once(
    tmp_path, capsys, monkeypatch, override, message
):
    """Issue 33: a run refused for a missing capture folder left run.failed/ (config.yaml, log.txt) and its error
    was printed twice (the log line on stderr, then the command line's message)."""
    monkeypatch.chdir(tmp_path)
    argv = tiny_capture_args(tmp_path, "output.dir=run")
    assert main([*argv, override]) == 2
    err = capsys.readouterr().err
    assert err.count(message) == 1 and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ps", "ps.yaml"]


def test_an_interrupted_run_is_logged_as_interrupted(tmp_path, capsys, monkeypatch):
    from torchrefl.capture import photometric_stereo

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(photometric_stereo.PhotometricStereoLoader, "load", interrupt)
    cfg = tmp_path / "ps.yaml"
    cfg.write_text(yaml.safe_dump({"capture": {"kind": "photometric_stereo", "path": "somewhere"}}))
    assert main([str(cfg), f"output.dir={tmp_path / 'run'}", "--quiet"]) == 130
    assert "torchrefl: interrupted" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
    log = (tmp_path / "run.failed" / "log.txt").read_text()
    assert "[capture] interrupted after" in log and "interrupted in stage 'capture'" in log
    assert "[capture] done" not in log


def test_metrics_json_is_strict():
    text = strict_json({"a": float("nan"), "b": [1.0, float("inf")], "c": {"d": -math.inf, "e": 2.5}})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict constant {c}")) == {
        "a": None,
        "b": [1.0, None],
        "c": {"d": None, "e": 2.5},
    }

"""python -m torchrefl.train CONFIG --resume: which unfinished run it continues (a failed run's NAME.failed, a killed
run's staging folder), what it takes from the checkpoints, and that a run of another config is never continued."""

import os

import pytest
from report.test_run_folder import tiny_capture_args

from torchrefl.core.checkpoints import FOLDER, Checkpoints
from torchrefl.report.run_marker import verify_run_folder
from torchrefl.report.run_resume import resumable_run
from torchrefl.train import main

DEAD_PID = 4194303  # above Linux's default pid_max: no process has it


@pytest.fixture
def stop_after_initialise(monkeypatch):
    """Runs stop (as if killed) right after the initialise checkpoint is written."""
    save = Checkpoints.save

    def stopping(self, name, state):
        save(self, name, state)
        if name == "initialise":
            raise KeyboardInterrupt

    monkeypatch.setattr(Checkpoints, "save", stopping)
    return monkeypatch


def test_a_failed_run_resumes_from_its_checkpoints_and_completes(tmp_path, stop_after_initialise, capsys):
    run = tmp_path / "run"
    argv = tiny_capture_args(tmp_path, f"output.dir={run}")
    assert main(argv) == 130
    failed = tmp_path / "run.failed"
    assert sorted(p.name for p in (failed / FOLDER).iterdir()) == ["capture.pt", "initialise.pt"]
    stop_after_initialise.undo()
    capsys.readouterr()
    assert main([*argv, "--resume"]) == 0
    err = capsys.readouterr().err
    assert f"continuing the unfinished run {failed}" in err
    assert "resume: capture from the checkpoint" in err and "start from the checkpoint" in err
    assert "[capture]" not in err.split("continuing")[1]  # the capture was not read again
    verify_run_folder(run)
    assert not (run / FOLDER).exists() and not failed.exists()
    log = (run / "log.txt").read_text()
    assert log.index("interrupted") < log.index("continuing the unfinished run")  # one log, both attempts


def test_a_killed_runs_staging_folder_is_resumed_and_another_configs_run_is_not(tmp_path, stop_after_initialise):
    run = tmp_path / "run"
    argv = tiny_capture_args(tmp_path, f"output.dir={run}", "--quiet")
    assert main(argv) == 130
    killed = tmp_path / f".run.staging-{DEAD_PID}"
    os.replace(tmp_path / "run.failed", killed)  # what a killed process leaves
    config = (killed / "config.yaml").read_text()
    assert resumable_run(run, config).folder == killed
    other = resumable_run(run, config.replace("seed: 0", "seed: 5"))
    assert other.folder is None and "made with another config" in other.note
    stop_after_initialise.undo()
    assert main([*argv, "--resume"]) == 0
    assert "continuing the unfinished run" in (run / "log.txt").read_text()
    assert not killed.exists()
    verify_run_folder(run)


def test_resume_without_an_unfinished_run_starts_anew(tmp_path, capsys):
    run = tmp_path / "run"
    assert main(tiny_capture_args(tmp_path, f"output.dir={run}", "--resume")) == 0
    assert "no unfinished run" in capsys.readouterr().err
    verify_run_folder(run)

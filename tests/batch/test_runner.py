"""A batch on Ray (one module-scoped local Ray session): a broken folder fails alone with its reason, a worker killed
mid-fit is retried and the retry resumes from the checkpoints, the summary is right, a re-run does no work; without
Ray the command says how to install it."""

import importlib.util
import json
import os
import signal

import pytest
import yaml
from capture.test_photometric_stereo import make_folder

from torchrefl.batch import read_batch, run_batch
from torchrefl.batch.__main__ import main
from torchrefl.batch.runner import _start
from torchrefl.batch.summary import read_summary

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def ray_session():
    _start(ray, None, 2)
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def mixed_batch(tmp_path_factory):
    """Two photometric stereo folders and one that holds no capture; fits without refinement (a second each)."""
    root = tmp_path_factory.mktemp("batch")
    for name in ("a", "b"):
        make_folder(root / "caps" / name)
    (root / "caps" / "broken").mkdir()
    (root / "base.yaml").write_text(yaml.safe_dump({"capture": {"kind": "photometric_stereo"}}))
    doc = {"base": "base.yaml", "captures": ["caps/*"], "overrides": ["fit.optimizer=none"], "output": "out"}
    (root / "batch.yaml").write_text(yaml.safe_dump({**doc, "retries": 1}))
    return root


def killed_once(marker):
    """A task function whose first attempt at capture 'a' kills its own worker after the initialise checkpoint."""

    def task(base, task, threads):
        from torchrefl.batch.task import run_task
        from torchrefl.core.checkpoints import Checkpoints

        if task.name == "a" and not marker.exists():
            marker.touch()
            save = Checkpoints.save

            def save_then_die(self, name, state):
                save(self, name, state)
                if name == "initialise":
                    os.kill(os.getpid(), signal.SIGKILL)

            Checkpoints.save = save_then_die
        return run_task(base, task, threads)

    return task


def test_a_broken_folder_fails_alone_and_a_killed_worker_is_retried(ray_session, mixed_batch, capsys):
    batch = read_batch(mixed_batch / "batch.yaml")
    rows = run_batch(batch, progress=False, task_fn=killed_once(mixed_batch / "killed"))
    by_name = {r.name: r for r in rows}
    assert [r.name for r in rows] == ["a", "b", "broken"]
    assert by_name["a"].status == by_name["b"].status == "complete" and by_name["a"].model == "local"
    assert by_name["broken"].status == "failed" and "cannot tell the capture kind" in by_name["broken"].error
    assert (mixed_batch / "killed").exists()  # the first attempt was killed
    log = (mixed_batch / "out" / "a" / "log.txt").read_text()
    assert "continuing the unfinished run" in log and "resume: capture from the checkpoint" in log
    assert read_summary(batch.output) == rows
    # the same command again: the two complete captures are skipped, the broken one fails again
    assert main([str(mixed_batch / "batch.yaml"), "--quiet"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == "1 of 3 captures failed (summary.csv has each one's error)"
    again = json.loads((batch.output / "summary.json").read_text())
    assert [(r["name"], r["status"]) for r in again] == [("a", "skipped"), ("b", "skipped"), ("broken", "failed")]


def test_without_ray_the_command_says_how_to_install_it(monkeypatch, mixed_batch, capsys):
    find = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else find(name, *a))
    assert main([str(mixed_batch / "batch.yaml")]) == 2
    assert 'pip install "torchrefl[ray]"' in capsys.readouterr().err

"""scripts/batch_targets.py: its tiny mode kills a photon fit of the tiny fold once its second outer iteration has
started (kill_runs.kill_when, the scripts' one run-killing helper) and resumes it: the resumed run redoes only the
second iteration and completes."""

import json

from conftest import load_script

batch_targets = load_script("batch_targets")


def test_tiny_mode_kills_in_the_second_outer_iteration_and_resumes(tmp_path, capsys):
    assert batch_targets.main(["--tiny", "--work", str(tmp_path)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    figures = next(f for f in lines if f.get("part") == "resume")
    assert figures["killed_after_s"] is not None  # killed, not finished first
    assert figures["refreshes_after_resume"] == ["photon refresh 2"]  # continued after outer iteration 1
    done = figures["killed_and_resumed_seed0"]
    assert done["kept_refresh"] in (0, 1, 2) and done["pd_rmse"] > 0
    assert (tmp_path / "killed" / "run_complete.json").is_file()
    assert not list(tmp_path.glob(".killed.staging-*"))  # the killed run's staging folder was taken up

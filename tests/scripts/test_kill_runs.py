"""scripts/kill_runs.py: its tiny mode kills a real run as it writes params.npz over a complete one, and load_run
then loads one whole run."""

from conftest import load_script

kill = load_script("kill_runs")


def test_tiny_mode_holds(tmp_path, capsys):
    assert kill.main(["--tiny", "--work", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("ok   params.npz written") and "earlier run" in lines[0]

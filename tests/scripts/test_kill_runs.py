"""scripts/kill_runs.py: its tiny mode kills a real run as its staging folder appears, and load_run then refuses the
fresh target with a named error."""

from conftest import load_script

kill = load_script("kill_runs")


def test_tiny_mode_holds(tmp_path, capsys):
    assert kill.main(["--tiny", "--work", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("ok   staging folder created") and "fresh folder" in lines[0]
    assert "load_run: named error" in lines[0]

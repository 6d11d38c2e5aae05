"""scripts/bench_configs.py: the timings table names the machine and the commands, never this machine's paths."""

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("bench_configs", ROOT / "scripts" / "bench_configs.py")
bench = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = bench  # dataclasses look their module up there
spec.loader.exec_module(bench)


def test_table_rows_and_machine():
    m = bench.Machine(cpu="Some CPU 9000", cores=2, threads=2, torch="2.13.0+cpu", python="3.11.7", system="Linux x")
    rows = [
        bench.Timing("quick", "python -m torchrefl.train configs/quick.yaml", 12.34, {"fit": 8.0, "total": 11.5}, 0.1),
        bench.Timing("diligent_ball", "", None, {}, 0.2, "skipped: no DiLiGenT ball folder (None)"),
    ]
    page = bench.table(rows, m, "python scripts/bench_configs.py --configs quick diligent_ball")
    assert "Machine: Some CPU 9000, 2 cores (Linux x), runs with `threads` 2; torch 2.13.0+cpu" in page
    assert "Written by `python scripts/bench_configs.py --configs quick diligent_ball` on " in page
    assert "| quick | `python -m torchrefl.train configs/quick.yaml` | 12.3 | fit 8.0; total 11.5 | 0.10 |" in page
    assert "| diligent_ball |  | skipped: no DiLiGenT ball folder (None) |  | 0.20 |" in page


def test_ball_missing_is_a_skipped_row_and_no_run(tmp_path):
    t = bench.run_config("diligent_ball", [], tmp_path, tmp_path / "no_ball")
    assert t.wall_s is None and t.note.startswith("skipped: no DiLiGenT ball folder")
    assert not (tmp_path / "diligent_ball").exists()


def test_failed_run_is_reported_with_its_error_and_the_ball_path_is_not_shown(tmp_path):
    ball = tmp_path / "my_ball"
    ball.mkdir()  # exists but empty: the run fails with the loader's error, after the command is built
    t = bench.run_config("diligent_ball", ["fit.iterations=-1"], tmp_path / "work", ball)
    assert t.wall_s is None and t.note.startswith("failed (exit 2):") and "fit.iterations" in t.note
    assert str(tmp_path) not in t.command and bench.BALL_SHOWN in t.command


def test_unknown_config_is_refused(capsys):
    with pytest.raises(SystemExit):
        bench.main(["--configs", "no_such_config"])
    assert "configs/no_such_config.yaml: no such bundled config" in capsys.readouterr().err

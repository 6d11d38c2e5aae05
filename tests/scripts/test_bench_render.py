"""scripts/bench_render.py: its tiny mode renders a frame and prints the timing line."""

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("bench_render", ROOT / "scripts" / "bench_render.py")
bench = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = bench
spec.loader.exec_module(bench)


def test_tiny_mode_prints_the_frame_time(capsys):
    assert bench.main(["--tiny", "--threads", "1"]) == 0
    line = capsys.readouterr().out
    assert line.startswith("64 x 64 frame: ") and "closest hits alone" in line

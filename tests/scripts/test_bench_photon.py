"""scripts/bench_photon.py: its tiny mode fits the tiny glossy fold with the photon level and prints the fit's time,
memory, accuracy and the ratios to bare Embree measured in the same run."""

import importlib.util
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("bench_photon", ROOT / "scripts" / "bench_photon.py")
bench = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = bench
spec.loader.exec_module(bench)


def test_tiny_mode_times_the_glossy_fit_against_bare_embree(tmp_path, capsys):
    assert bench.main(["--tiny", "--threads", "1", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    assert "fit (precompute + initialise + fit): " in text and "of bare Embree on the same rays replayed" in text
    report = json.loads((tmp_path / "bench_photon.json").read_text())
    e = report["end_to_end"]
    # the real glossy configuration: the radiosity level's all-diffuse paths and the specular gather ran
    assert e["photon"]["cache"]["gather_rays"] > 0 and e["photon"]["cache"]["radiosity_irradiance_mean"] > 0
    assert len(e["refresh_at_s"]) == len(e["image_difference_per_refresh"]) == 2
    assert e["peak_memory_mb"] > 100 and e["fit_cpu_s"] > 0
    pt = report["photon_tracing"]
    assert 0 < pt["tracing_ratio_to_bare_replay"] and pt["rays"] > 0
    assert report["form_factors"]["rays"] > 0

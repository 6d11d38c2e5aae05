"""scripts/bench_rays.py: its tiny mode prints both queries' rates and ratios to bare Embree."""

from conftest import load_script

bench = load_script("bench_rays")


def test_tiny_mode_prints_both_queries_against_bare_embree(capsys):
    assert bench.main(["--tiny"]) == 0
    out = capsys.readouterr().out
    assert "20000 rays" in out and "ours2t/raw2t" in out
    rows = [line.split() for line in out.splitlines() if line.strip().startswith(("closest", "occlusion"))]
    assert len(rows) == 2 and all(float(v) > 0 for row in rows for v in row[-7:])

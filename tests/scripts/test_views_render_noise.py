"""scripts/views_render_noise.py: its tiny mode renders the bowl's pixels twice and prints the noise."""

from conftest import load_script

import torchrefl.synthetic.path_tracer as path_tracer

noise = load_script("views_render_noise")


def test_tiny_mode_prints_the_noise_and_leaves_the_renderer_as_it_was(capsys):
    plain = path_tracer.IndirectRenderer.__init__
    assert noise.main(["--tiny"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("2 paths, bounces 2..4, 40 px x ") and "noise" in out
    assert path_tracer.IndirectRenderer.__init__ is plain

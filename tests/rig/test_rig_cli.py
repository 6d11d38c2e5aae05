"""python -m torchrefl.rig: dry runs against the simulated device, and error reporting."""

import numpy as np
import pytest
from rig_helpers import assert_consistent

from torchrefl.capture.cylindrical_scan import read_scan_yaml
from torchrefl.rig.__main__ import main

SCENE = [
    "--scene-set",
    "synthetic.rows=48",
    "--scene-set",
    "synthetic.columns=48",
    "--scene-set",
    "synthetic.angle_step_deg=7.5",
    "--scene-set",
    "synthetic.height_step_mm=4.4",
    "--scene-set",
    "synthetic.supersample=1",
    "--scene-set",
    "synthetic.mesh_subdivisions=3",
]
FAST = ["--set", "light.settle_s=0", "--set", "timeouts.poll_s=0.005"]


def test_dry_run_capture_writes_a_loadable_folder_and_resumes(tmp_path, capsys):
    out = tmp_path / "cap"
    args = ["capture", "--dry-run", "--grid-positions", "0,0", "9,5", "4,2", "--out", str(out)] + SCENE + FAST
    assert main(args) == 0
    streams = capsys.readouterr()
    assert "capture complete: 3 new" in streams.out and "textures/" not in streams.out  # the result on stdout
    assert "[3/3] textures/" in streams.err and "capture complete" not in streams.err  # progress on stderr
    entries = assert_consistent(out)
    doc = read_scan_yaml(out)  # the fitting side's reader
    assert doc["lights"] == [dict(e) for e in doc["lights"]] and len(doc["lights"]) == 3
    assert sorted(tuple(e["position_mm"]) for e in doc["lights"]) == sorted(
        [(-225.0, 125.0, 300.0), (225.0, -125.0, 300.0), (-25.0, 25.0, 300.0)]
    )
    assert (out / "range.npy").is_file() and (out / "truth.npz").is_file()
    assert np.load(out / "range.npy").shape == (48, 48)
    # run again with one more position: only the new one is shot
    assert main(args[:6] + ["1,1", "--out", str(out), "--quiet"] + SCENE + FAST) == 0
    streams = capsys.readouterr()
    assert "1 new, 3 already recorded" in streams.out and streams.err == ""  # --quiet: no progress lines
    assert len(assert_consistent(out)) == 4
    assert {e["image"] for e in entries} < {e["image"] for e in assert_consistent(out)}


def test_probe_home_move_dry_run(capsys):
    """Issue 33: every command's result goes to stdout, its progress (dry-run notes, homing) to stderr."""
    assert main(["probe", "--dry-run"]) == 0
    streams = capsys.readouterr()
    assert "Grbl 1.1h ['$' for help]; state Alarm" in streams.out and "$130=496" in streams.out
    assert "dry run: simulated GRBL" in streams.err and "dry run" not in streams.out
    assert main(["move", "--dry-run", "--grid", "2", "1"] + FAST) == 0
    streams = capsys.readouterr()
    assert streams.out.strip().startswith("reached head-frame [-125.0, 75.0, 300.0]")
    assert "homed: MPos" in streams.err and "dry run: simulated GRBL" in streams.err


@pytest.mark.parametrize(
    "argv, message",
    [
        (["probe", "--dry-run", "--set", "lateral.axes=X"], "unknown key 'lateral.axes'"),
        (
            ["move", "--dry-run", "--mm", "10", "0", "--set", "lateral.max_mm=-250"],
            "lateral axis X target -240.000 is outside the travel .* nothing was sent",
        ),
        (["move", "--dry-run", "--grid", "10", "0"], r"grid index \(10, 0\) outside the 10 x 6 light grid"),
        (["probe", "--port", "/nonexistent/ttyACM9"], "cannot open serial port /nonexistent/ttyACM9"),
        (["capture", "--port", "loop://", "--all-grid", "--out", "unused"], "camera.command is empty"),
    ],
)
def test_errors_are_one_line_messages(argv, message, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err  # progress lines (dry run), then the error, once, on its last line
    assert err.splitlines()[-1].startswith("error: ") and err.count("error: ") == 1 and "Traceback" not in err
    import re

    assert re.search(message, err.splitlines()[-1]), err

"""Camera triggers: external command template and the simulated camera."""

import sys

import numpy as np
import pytest

from torchrefl.capture.images import read_image
from torchrefl.errors import RigError
from torchrefl.rig.camera import ExternalCommandCamera, SimulatedCamera

PY = sys.executable


def test_external_command_writes_the_file(tmp_path):
    cam = ExternalCommandCamera(f"{PY} -c \"import sys; open(sys.argv[1], 'wb').write(b'img')\" {{path}}")
    out = tmp_path / "with space" / "a.png"
    out.parent.mkdir()
    cam.capture(out)
    assert out.read_bytes() == b"img"


def test_external_command_failures(tmp_path):
    with pytest.raises(RigError, match="exited with status 3: boom"):
        ExternalCommandCamera(f"{PY} -c \"import sys; sys.stderr.write('boom'); sys.exit(3)\" {{path}}").capture(
            tmp_path / "a.png"
        )
    with pytest.raises(RigError, match="succeeded but wrote no image"):
        ExternalCommandCamera(f"{PY} -c pass {{path}}").capture(tmp_path / "b.png")
    with pytest.raises(RigError, match="did not finish within 0.2 s"):
        ExternalCommandCamera(f'{PY} -c "import time; time.sleep(5)" {{path}}', timeout_s=0.2).capture(
            tmp_path / "c.png"
        )
    with pytest.raises(RigError, match="not found"):
        ExternalCommandCamera("no-such-camera-tool {path}").capture(tmp_path / "d.png")
    with pytest.raises(RigError, match="no \\{path\\} placeholder"):
        ExternalCommandCamera("gphoto2 --capture-image")


def test_simulated_camera_writes_the_rendered_png(tmp_path):
    seen = []

    def render(p):
        seen.append(p)
        return np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1000

    cam = SimulatedCamera(render)
    cam.capture(tmp_path / "x.png", [1.0, 2.0, 3.0])
    img, bits = read_image(tmp_path / "x.png")
    assert bits == 16 and np.array_equal(np.rint(img * 65535).astype(np.uint16), render(None))
    assert np.array_equal(seen[0], [1.0, 2.0, 3.0]) and cam.calls == 1
    with pytest.raises(RigError, match="needs the light position"):
        cam.capture(tmp_path / "y.png")
    bad = SimulatedCamera(lambda p: np.full((2, 2, 3), 2.0))
    with pytest.raises(RigError, match="simulated camera: .*z.png"):
        bad.capture(tmp_path / "z.png", [0, 0, 0])

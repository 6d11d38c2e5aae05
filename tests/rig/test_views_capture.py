"""The rig on a mesh_views plan against the fake GRBL device: per image the light at its gantry position and the
camera the plan names; images.json and lights.json written from the manifest, so the folder loads with the
mesh_views loader."""

import json

import numpy as np
import pytest
from rig_helpers import assert_consistent, client_for, fake_device, fast_settings

from torchrefl.capture.mesh_views import MeshViewsLoader
from torchrefl.config import load_config
from torchrefl.errors import ConfigError, RigError
from torchrefl.rig.camera import ExternalCommandCamera, SimulatedCamera
from torchrefl.rig.dry_run import prepare_folder, synthetic_scene
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import load_plan
from torchrefl.rig.runner import CaptureRunner

#: the gantry plane 350 mm in front of the origin, lateral along +x, vertical along +y
GANTRY = {"origin_mm": [0.0, 0.0, 350.0], "lateral": [1.0, 0.0, 0.0], "vertical": [0.0, 1.0, 0.0]}
LIGHTS = [
    {"name": "La", "position_mm": [-100.0, 50.0, 350.0], "gantry_mm": [-100.0, 50.0]},
    {"name": "Lb", "position_mm": [100.0, 0.0, 350.0], "gantry_mm": [100.0, 0.0]},
]
IMAGES = [{"camera": "cam00", "light": "La"}, {"camera": "cam02", "light": "La"}, {"camera": "cam00", "light": "Lb"}]
#: configs/mesh_views.yaml's scene, small: 4 cameras of 160 x 120 px, a 32 x 32 atlas, no noise
SCENE = [
    "views.width=160",
    "views.height=120",
    "views.focal_px=260",
    "views.cameras_per_ring=2",
    "views.camera_elevations_deg=[0,40]",
    "views.supersample=1",
    "views.noise_dn=0",
    "capture.texture_size=32",
]


def write_plan(path, **changes):
    doc = {"kind": "mesh_views", "layout": "gantry", "gantry": GANTRY, "lights": LIGHTS, "images": IMAGES}
    doc.update(changes)
    path.write_text(json.dumps(doc))
    return path


def run(folder, plan, camera, settings):
    model = RigModel(settings)
    with fake_device() as fake:
        client = client_for(fake)
        runner = CaptureRunner(client, model, camera, CaptureFolder(folder), settings, progress=lambda m: None)
        try:
            return runner.run(load_plan(plan, model))
        finally:
            client.link.close()


class Recording(SimulatedCamera):
    """Records (world position, camera) per shot; a 4 x 3 image."""

    def __init__(self):
        super().__init__(lambda position, camera: np.full((3, 4, 3), 9, np.uint8))
        self.shots = []

    def capture(self, path, position_mm=None, camera=None):
        self.shots.append((tuple(np.round(position_mm, 3)), camera))
        super().capture(path, position_mm, camera)


def test_each_image_moves_the_light_and_triggers_its_camera(tmp_path):
    cam = Recording()
    settings = fast_settings(light={"intensity": [1000.0, 2000.0, 3000.0]})
    summary = run(tmp_path / "cap", write_plan(tmp_path / "plan.json"), cam, settings)
    assert summary["captured"] == 3
    # the camera is given the light's world position on the gantry plane (origin + lateral x + vertical y)
    assert sorted(cam.shots) == sorted(
        [((-100.0, 50.0, 350.0), "cam00"), ((-100.0, 50.0, 350.0), "cam02"), ((100.0, 0.0, 350.0), "cam00")]
    )
    entries = assert_consistent(tmp_path / "cap")
    images = json.loads((tmp_path / "cap" / "images.json").read_text())
    assert images["cameras"] == "cameras.json" and images["encoding"] == "linear"
    assert sorted((im["camera"], im["light"]) for im in images["images"]) == sorted(
        (im["camera"], im["light"]) for im in IMAGES
    )
    assert {im["file"] for im in images["images"]} == {e["image"] for e in entries}
    lights = json.loads((tmp_path / "cap" / "lights.json").read_text())
    assert lights == {
        "La": {"position": [-100.0, 50.0, 350.0], "intensity": [1000.0, 2000.0, 3000.0]},
        "Lb": {"position": [100.0, 0.0, 350.0], "intensity": [1000.0, 2000.0, 3000.0]},
    }
    # a second run finds every image recorded: nothing is shot again
    again = run(tmp_path / "cap", tmp_path / "plan.json", cam, settings)
    assert again["captured"] == 0 and again["skipped"] == 3 and len(cam.shots) == 3


def test_a_plan_off_the_gantry_plane_is_refused(tmp_path):
    plan = write_plan(tmp_path / "dome.json", layout="dome", gantry=None)
    with pytest.raises(ConfigError, match="dome.json: a mesh_views plan of layout 'dome'.*gantry"):
        load_plan(plan, RigModel(fast_settings()))
    plan = write_plan(tmp_path / "bad.json", images=[{"camera": "cam00", "light": "Lz"}])
    with pytest.raises(ConfigError, match=r"bad.json: images\[0\]"):
        load_plan(plan, RigModel(fast_settings()))


def test_a_trigger_command_must_name_the_camera_when_the_plan_names_several():
    with pytest.raises(RigError, match=r"no \{camera\} placeholder.*2 cameras"):
        ExternalCommandCamera("shoot {path}").check_cameras(["cam00", "cam02", "cam00"])
    ExternalCommandCamera("shoot {path}").check_cameras(["cam00"])
    ExternalCommandCamera("shoot --camera {camera} {path}").check_cameras(["cam00", "cam02"])


def test_the_captured_folder_loads_with_the_mesh_views_loader(tmp_path):
    scene = synthetic_scene("mesh_views", SCENE)
    folder = prepare_folder(scene, tmp_path / "cap")
    settings = fast_settings(light={"intensity": [float(v) for v in scene.light_intensity]})
    run(folder, write_plan(tmp_path / "plan.json"), SimulatedCamera(scene.render_texture), settings)
    cfg = load_config("mesh_views", [*SCENE, "capture.kind=mesh_views", f"capture.path={folder}"])
    capture = MeshViewsLoader().load(folder, cfg, lambda m: None)
    obs = capture.obs
    assert obs.intensity.shape[0] == 3
    # each image's light is where the plan put it, and its camera sees part of the object
    at = sorted(tuple(p) for p in np.round(obs.light_positions.numpy().astype(np.float64), 3))
    assert at == [(-100.0, 50.0, 350.0), (-100.0, 50.0, 350.0), (100.0, 0.0, 350.0)]
    assert (obs.valid.sum(1) > 0).all()

"""Shared helpers for the rig tests: a fast fake device, a connected client, fast settings, a
counting camera and the folder consistency check."""

import json
import re
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from torchrefl.rig.camera import SimulatedCamera
from torchrefl.rig.fake_grbl import FakeGrbl
from torchrefl.rig.grbl import GrblClient
from torchrefl.rig.link import SerialLink
from torchrefl.rig.settings import load_rig_settings

FAST = dict(time_scale=0.01)


class ManualClock:
    """A clock for FakeGrbl(clock=...): simulated time moves only when a test calls advance()."""

    def __init__(self):
        self.t = 0.0

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds


@contextmanager
def fake_device(**kw):
    args = dict(FAST)
    args.update(kw)
    fake = FakeGrbl(**args).start()
    try:
        yield fake
    finally:
        fake.stop()


def client_for(fake, **kw) -> GrblClient:
    args = dict(reply_s=1.0, banner_s=0.2, poll_s=0.005, home_s=2.0, move_s=5.0)
    args.update(kw)
    return GrblClient(SerialLink(fake.path), **args)


def connected(fake, **kw) -> GrblClient:
    c = client_for(fake, **kw)
    c.link.open()
    c.connect()
    return c


def fast_settings(**data):
    base = {
        "light": {"settle_s": 0.0},
        "timeouts": {"reply_s": 1.0, "banner_s": 0.2, "poll_s": 0.005, "home_s": 2.0, "move_s": 5.0},
    }
    for k, v in data.items():
        if isinstance(v, dict):
            base.setdefault(k, {}).update(v)
        else:
            base[k] = v
    return load_rig_settings(data=base)


def render(position_mm) -> np.ndarray:
    """A small image that encodes the light position (so files can be matched to positions)."""
    lat, vert, _ = position_mm
    img = np.zeros((6, 5, 3), np.uint8)
    img[..., 0] = int(round(lat)) % 256
    img[..., 1] = int(round(vert)) % 256
    img[..., 2] = 7
    return img


class CountingCamera(SimulatedCamera):
    """SimulatedCamera recording every call per position; raises `interrupt` on call number fail_at (1-based)."""

    def __init__(self, fail_at=None, interrupt=KeyboardInterrupt):
        super().__init__(render)
        self.attempts = []
        self.shots = {}
        self.fail_at, self.interrupt = fail_at, interrupt

    def capture(self, path, position_mm=None):
        key = tuple(round(float(v), 3) for v in position_mm)
        self.attempts.append(key)
        if self.fail_at is not None and len(self.attempts) == self.fail_at:
            raise self.interrupt()
        super().capture(path, position_mm)
        self.shots[key] = self.shots.get(key, 0) + 1


def assert_consistent(folder) -> list:
    """Every manifest entry has its image, every image has its entry, no temp files, indices and
    images unique, every line a complete JSON object. Returns the entries."""
    folder = Path(folder)
    manifest = folder / "manifest.jsonl"
    entries = []
    if manifest.exists():
        text = manifest.read_text()
        assert text == "" or text.endswith("\n"), "manifest ends in a partial line"
        entries = [json.loads(line) for line in text.splitlines() if line.strip()]
    images = [e["image"] for e in entries]
    indices = [e["index"] for e in entries]
    assert len(set(indices)) == len(indices), f"repeated indices {indices}"
    assert len(set(images)) == len(images), f"repeated images {images}"
    for e in entries:
        assert (folder / e["image"]).is_file(), f"entry {e['index']} has no image {e['image']}"
        assert set(e) >= {"index", "image", "position_mm", "requested_mm", "mpos", "grid", "time"}
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", e["time"])
    tex = folder / "textures"
    files = sorted(p.name for p in tex.iterdir()) if tex.exists() else []
    assert not [f for f in files if not re.fullmatch(r"\d{3,}\.png", f)], f"stray files {files}"
    assert sorted("textures/" + f for f in files) == sorted(images), "images without entries"
    return entries

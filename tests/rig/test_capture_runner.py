"""The capture runner against the fake GRBL device: complete runs, soft limits, and every fault
ends in a completed capture or a clear RigError with a consistent folder; restarts shoot each
position exactly once."""

import numpy as np
import pytest
from rig_helpers import CountingCamera, assert_consistent, client_for, fake_device, fast_settings, render

from torchrefl.capture.cylindrical_scan import read_manifest
from torchrefl.capture.images import read_image
from torchrefl.errors import RigError
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.grbl import ControllerReset, GrblAlarm, GrblErrorReply
from torchrefl.rig.link import NoReply, PortLost
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import targets_from_grid
from torchrefl.rig.runner import CaptureRunner

NODES = [(0, 0), (3, 1), (9, 5), (5, 2), (1, 4), (7, 0), (2, 2), (8, 3)]


def _run(fake, folder, camera, settings=None, nodes=NODES, progress=None):
    settings = settings or fast_settings()
    model = RigModel(settings)
    client = client_for(fake)
    runner = CaptureRunner(
        client, model, camera, CaptureFolder(folder), settings, progress=progress or (lambda m: None)
    )
    try:
        return runner.run(targets_from_grid(model, nodes)), model
    finally:
        client.link.close()


def _expected_positions(settings, nodes=NODES):
    model = RigModel(settings)
    return sorted(tuple(model.grid_position(i, j).tolist()) for i, j in nodes)


def _each_shot_once(camera, settings, nodes=NODES):
    want = {tuple(round(v, 3) for v in p) for p in _expected_positions(settings, nodes)}
    assert set(camera.shots) == want
    assert all(n == 1 for n in camera.shots.values()), camera.shots


def test_complete_capture_records_reached_positions(tmp_path):
    settings = fast_settings()
    cam = CountingCamera()
    with fake_device() as fake:
        summary, model = _run(fake, tmp_path, cam, settings)
        assert not fake.coolant
        assert fake.outputs_log == [("coolant", True), ("coolant", False)] * len(NODES)
    assert summary["captured"] == len(NODES) and summary["skipped"] == 0
    entries = assert_consistent(tmp_path)
    assert sorted(tuple(e["position_mm"]) for e in entries) == _expected_positions(settings)
    for e in entries:
        # the reached position is the model's reading of the controller's MPos (origin -250/-150, sign +1)
        assert e["position_mm"] == pytest.approx([e["mpos"][0] + 250.0, e["mpos"][1] + 150.0, 300.0])
        assert tuple(e["grid"]) in NODES
        img, bits = read_image(tmp_path / e["image"])
        assert bits == 8
        assert np.array_equal(np.rint(img * 255).astype(np.uint8), render(e["position_mm"]))
    assert [e["index"] for e in read_manifest(tmp_path / "manifest.jsonl")] == list(range(len(NODES)))
    _each_shot_once(cam, settings)


def test_order_is_shorter_than_the_given_order(tmp_path):
    cam = CountingCamera()
    settings = fast_settings()
    with fake_device() as fake:
        summary, model = _run(fake, tmp_path, cam, settings)
    pts = np.array([model.grid_position(i, j)[:2] for i, j in NODES])
    start = np.array([249.0, 149.0])  # head-frame position of MPos (-1, -1) after homing
    given = np.linalg.norm(np.diff(np.vstack([start, pts]), axis=0), axis=1).sum()
    assert summary["path_mm"] < given


def test_soft_limit_refusal_sends_nothing(tmp_path):
    settings = fast_settings(lateral={"max_mm": -100.0})  # grid column 9 (lateral 225) needs X = -25
    with fake_device() as fake:
        with pytest.raises(RigError, match="lateral axis X target -25.000 is outside the travel .*nothing was sent"):
            _run(fake, tmp_path, CountingCamera(), settings)
        assert bytes(fake.received) == b""
    assert assert_consistent(tmp_path) == []


def test_alarm_mid_move_stops_consistently_and_restart_completes(tmp_path):
    settings = fast_settings()
    cam = CountingCamera()
    with fake_device() as fake:
        fake.alarm_during_move(3, code=1)
        with pytest.raises(GrblAlarm, match="ALARM:1 .Hard limit"):
            _run(fake, tmp_path, cam, settings)
        assert not fake.coolant
        assert len(assert_consistent(tmp_path)) == 2
        summary, _ = _run(fake, tmp_path, cam, settings)  # reset + home, then the rest
    assert summary["skipped"] == 2 and summary["captured"] == len(NODES) - 2
    assert len(assert_consistent(tmp_path)) == len(NODES)
    _each_shot_once(cam, settings)


def test_port_vanishes_and_returns_capture_resumes(tmp_path):
    settings = fast_settings(timeouts={"reconnect_s": 3.0})
    cam = CountingCamera()
    with fake_device() as fake:
        fake.vanish_during_move(4, down_s=0.3)
        summary, _ = _run(fake, tmp_path, cam, settings)
        assert fake.power_ups == 2 and not fake.coolant
    assert summary["reconnects"] == 1 and summary["captured"] == len(NODES)
    assert len(assert_consistent(tmp_path)) == len(NODES)
    _each_shot_once(cam, settings)


def test_port_vanishes_without_reconnect_then_rerun(tmp_path):
    settings = fast_settings()
    cam = CountingCamera()
    with fake_device() as fake:
        fake.vanish_during_move(4, down_s=None)
        with pytest.raises(PortLost, match="serial port .*ttyGRBL"):
            _run(fake, tmp_path, cam, settings)
        assert len(assert_consistent(tmp_path)) == 3
        fake.come_back()
        client = client_for(fake)
        client.link.reopen(3.0)
        client.link.close()
        summary, _ = _run(fake, tmp_path, cam, settings)
    assert summary["skipped"] == 3
    assert len(assert_consistent(tmp_path)) == len(NODES)
    _each_shot_once(cam, settings)


def test_reset_banner_mid_plan_is_detected(tmp_path):
    settings = fast_settings()
    cam = CountingCamera()
    with fake_device() as fake:
        fake.reboot_during_move(5)
        with pytest.raises(ControllerReset, match="reset unexpectedly"):
            _run(fake, tmp_path, cam, settings)
        assert len(assert_consistent(tmp_path)) == 4
        _run(fake, tmp_path, cam, settings)
    assert len(assert_consistent(tmp_path)) == len(NODES)
    _each_shot_once(cam, settings)


def test_after_a_reboot_nothing_is_sent_to_the_locked_board_and_the_message_says_what_resume_does(tmp_path):
    notes = []
    with fake_device() as fake:
        fake.reboot_during_move(5)
        with pytest.raises(ControllerReset, match="outputs .*off.*locked until homed"):
            _run(fake, tmp_path, CountingCamera(), progress=notes.append)
        after_reboot = fake.lines[[k for k, s in enumerate(fake.lines) if s.startswith("G21 G90 G53")][4] + 1 :]
        assert after_reboot == [] and not fake.coolant  # no M9 (error:9) to the locked board
    assert "light off failed" not in notes[-1]
    assert "the controller rebooted" in notes[-1] and "it homes ($H) first, then shoots the 4 positions" in notes[-1]


def test_reset_banner_mid_plan_rehome_option_continues(tmp_path):
    settings = fast_settings(rehome_on_reset=True)
    cam = CountingCamera()
    with fake_device() as fake:
        fake.reboot_during_move(5)
        summary, _ = _run(fake, tmp_path, cam, settings)
    assert summary["rehomes"] == 1
    entries = assert_consistent(tmp_path)
    assert sorted(tuple(e["position_mm"]) for e in entries) == _expected_positions(settings)
    _each_shot_once(cam, settings)


@pytest.mark.parametrize("k", [1, 4, len(NODES)])
def test_keyboard_interrupt_from_camera_then_restart(tmp_path, k):
    settings = fast_settings()
    cam = CountingCamera(fail_at=k)
    with fake_device() as fake:
        with pytest.raises(KeyboardInterrupt):
            _run(fake, tmp_path, cam, settings)
        assert not fake.coolant  # switched off on the way out
        assert len(assert_consistent(tmp_path)) == k - 1
        _run(fake, tmp_path, cam, settings)
    assert len(assert_consistent(tmp_path)) == len(NODES)
    assert len(cam.attempts) == len(NODES) + 1  # only the interrupted shot was repeated
    _each_shot_once(cam, settings)


def test_silent_controller_mid_plan_is_a_timeout(tmp_path):
    settings = fast_settings()
    with fake_device() as fake:
        fake.silence(after_line="M8")
        with pytest.raises(NoReply, match="no reply from .*ttyGRBL within 1.0 s to 'M8'"):
            _run(fake, tmp_path, CountingCamera(), settings)
    assert assert_consistent(tmp_path) == []


def test_error_reply_mid_plan(tmp_path):
    settings = fast_settings()
    with fake_device() as fake:
        fake.error_on("G53", 33, skip=2)
        with pytest.raises(GrblErrorReply, match="error:33"):
            _run(fake, tmp_path, CountingCamera(), settings)
        assert not fake.coolant
    assert len(assert_consistent(tmp_path)) == 2


def test_garbage_mid_plan_is_survived(tmp_path):
    settings = fast_settings()
    with fake_device() as fake:
        fake.garbage_before("M8", b"\xfe\xff\x00\x9c\r\n")
        fake.garbage_before("M9", b"<Idle|MPos:oops>\r\n")
        summary, _ = _run(fake, tmp_path, CountingCamera(), settings)
    assert summary["captured"] == len(NODES)
    assert len(assert_consistent(tmp_path)) == len(NODES)


def test_spindle_light_switch(tmp_path):
    settings = fast_settings(light={"output": "spindle", "spindle_power": 750.0})
    with fake_device() as fake:
        _run(fake, tmp_path, CountingCamera(), settings, nodes=NODES[:2])
        assert fake.outputs_log == [("spindle", True), ("spindle", False)] * 2
        assert "M3S750" in [s.replace(" ", "") for s in fake.lines]

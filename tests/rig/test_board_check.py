"""The board's `$$` against the rig config: every refusal names the setting, the config key and the
command that fixes it, and nothing moves; probe prints the checks; the no-switch override warns."""

import pytest
from rig_helpers import (
    CountingCamera,
    assert_consistent,
    client_for,
    fake_device,
    fast_settings,
)

from torchrefl.errors import ConfigError, RigError
from torchrefl.rig.__main__ import main
from torchrefl.rig.board_check import check_board, machine_travel, require_board
from torchrefl.rig.fake_settings import DEFAULT_SETTINGS
from torchrefl.rig.folder import CaptureFolder
from torchrefl.rig.model import RigModel
from torchrefl.rig.plan import targets_from_grid
from torchrefl.rig.runner import CaptureRunner


def _board(**changes):
    board = {k: float(v) for k, v in DEFAULT_SETTINGS.items()}
    board.update({int(k[1:]): float(v) for k, v in changes.items()})
    return board


def test_default_board_fits_the_default_config():
    checks = check_board(_board(), fast_settings())
    assert [c.setting for c in checks] == ["$13", "$22", "$20", "$130", "$131"]
    assert all(c.ok for c in checks)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"s20": 0}, r"\$20 \(soft limits\) is 0, expected 1: send `\$20=1`"),
        (
            {"s22": 0, "s20": 0},
            r"\$22 \(homing\) is 0.*send `\$22=1`.*board.limit_switches: false.*\$20 .*after `\$22=1`",
        ),
        ({"s13": 1}, r"\$13 \(report inches\) is 1, expected 0: send `\$13=0`"),
        (
            {"s130": 300},
            (
                r"\$130 .* is 300, expected \[-300, -1\].*set lateral.min_mm >= -300 in the rig config, "
                r"or send `\$130=495`"
            ),
        ),
        ({"s27": 10}, r"set lateral.max_mm <= -10 .*set vertical.max_mm <= -10"),
    ],
)
def test_refusals_name_setting_key_and_command(changes, message):
    with pytest.raises(RigError, match=message):
        require_board(_board(**changes), fast_settings(), "ttyX")


def test_travel_follows_the_homing_direction_and_pull_off():
    assert machine_travel(_board(), 0) == (-500.0, -1.0)
    assert machine_travel(_board(s23=1), 0) == (-499.0, 0.0)  # X homes towards -: switch at -500
    assert machine_travel(_board(s23=1), 1) == (-300.0, -1.0)
    with pytest.raises(RigError, match=r"\$130 .*set lateral.max_mm <= 0 "):
        require_board(_board(s23=1), fast_settings(lateral={"min_mm": -499.5, "max_mm": 5.0}), "ttyX")


def test_spindle_light_needs_laser_mode_off_and_turntable_axis_is_checked():
    s = fast_settings(light={"output": "spindle"}, turntable={"enabled": True, "min_mm": -100.0, "max_mm": -2.0})
    checks = check_board(_board(s32=1), s)
    bad = {c.setting: c.fix for c in checks if c.ok is False}
    assert set(bad) == {"$32"} and "`$32=0`" in bad["$32"]
    assert [c.setting for c in checks] == ["$13", "$22", "$20", "$130", "$131", "$132", "$32"]


def test_limit_switch_override_skips_switch_checks_and_needs_no_homing():
    s = fast_settings(board={"limit_switches": False}, home_on_start=False)
    checks = check_board(_board(s22=0, s20=0, s130=10), s)
    assert [c.ok for c in checks] == [True, None, None, None, None]
    with pytest.raises(ConfigError, match="board.limit_switches is false .* home_on_start"):
        fast_settings(board={"limit_switches": False})


def _capture(fake, folder, settings, progress):
    model = RigModel(settings)
    client = client_for(fake)
    runner = CaptureRunner(client, model, CountingCamera(), CaptureFolder(folder), settings, progress=progress)
    try:
        return runner.run(targets_from_grid(model, [(0, 0), (9, 5)]))
    finally:
        client.link.close()


def test_capture_refuses_a_board_without_soft_limits_before_anything_moves(tmp_path):
    with fake_device(settings={20: 0, 130: 400.0}) as fake:
        with pytest.raises(RigError, match=r"`\$20=1`.*lateral.min_mm >= -400.*`\$130=495`"):
            _capture(fake, tmp_path, fast_settings(), lambda m: None)
        assert fake.moves_started == 0 and "$H" not in fake.lines and "$$" in fake.lines
    assert assert_consistent(tmp_path) == []


def test_capture_on_a_machine_without_switches_warns_and_runs(tmp_path):
    notes = []
    settings = fast_settings(
        board={"limit_switches": False},
        home_on_start=False,
        lateral={"min_mm": -495.0, "max_mm": 495.0},
        vertical={"min_mm": -295.0, "max_mm": 295.0},
    )
    with fake_device(settings={22: 0}) as fake:
        summary = _capture(fake, tmp_path, settings, notes.append)
    assert summary["captured"] == 2
    assert any(n.startswith("WARNING: board.limit_switches: false") and "NOT checked" in n for n in notes)


def test_cli_move_beyond_the_machine_travel_is_refused(capsys):
    # the case: config limits wider than the 500 mm axis and soft limits off
    with fake_device(settings={20: 0}) as fake:
        argv = [
            "move",
            "--port",
            fake.path,
            "--mm",
            "-340",
            "0",
            "--set",
            "lateral.min_mm=-600",
            "--set",
            "timeouts.poll_s=0.005",
            "--set",
            "timeouts.banner_s=0.2",
        ]
        assert main(argv) == 2
        assert fake.moves_started == 0 and "$H" not in fake.lines
    err = capsys.readouterr().err
    assert "`$20=1`" in err and "set lateral.min_mm >= -500" in err and "`$130=600`" in err


def test_cli_probe_prints_the_checks_and_fails_on_a_bad_board(capsys):
    with fake_device(settings={13: 1}) as fake:
        assert main(["probe", "--port", fake.path, "--set", "timeouts.banner_s=0.2"]) == 2
    captured = capsys.readouterr()
    assert "board settings checked against the rig config:" in captured.out
    assert "$13=1 (report inches): WRONG, expected 0; send `$13=0`" in captured.out
    assert "$20=1 (soft limits): ok, expected 1" in captured.out
    assert "error: " in captured.err and "`$13=0`" in captured.err

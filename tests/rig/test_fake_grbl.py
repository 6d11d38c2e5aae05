"""The fake board behaves as the real Grbl 1.1h does (issue 20): `$22=0` clears `$20`, `$J=` jogs
with error:15, error:8 for `$` while moving, the leftover `ok` after a soft-limit alarm, acceleration,
two-phase feed hold, homing time from the settings, `Ov:`/`A:` report fields. Simulated time follows a
ManualClock, so nothing here depends on how fast the machine runs the test."""

import time

import pytest
from rig_helpers import ManualClock, connected, fake_device

from torchrefl.rig.fake_motion import trapezoid_seconds
from torchrefl.rig.grbl import GrblAlarm, GrblErrorReply, parse_status
from torchrefl.rig.grbl_homing import homing_seconds


def _unlocked(fake):
    c = connected(fake)
    c.unlock()  # MPos 0, soft limits on: machine space [-$13x, 0]
    return c


def test_homing_off_clears_soft_limits_and_soft_limits_need_homing():
    with fake_device() as fake:
        c = connected(fake)
        assert c.read_settings()[20] == 1.0
        c.command("$22=0")
        assert c.read_settings()[20] == 0.0  # Grbl: homing off forces soft limits off
        with pytest.raises(GrblErrorReply, match="error:10 .*Soft limits cannot be enabled without homing"):
            c.command("$20=1")
        c.command("$22=1")
        c.command("$20=1")
        assert c.read_settings()[20] == 1.0
        c.link.close()


def test_jog_runs_in_jog_state_and_error_15_beyond_the_travel():
    clock = ManualClock()
    with fake_device(clock=clock, time_scale=1.0) as fake:
        c = _unlocked(fake)
        c.command("$J=G91 G21 X-10 F1000")
        assert c.status().state == "Jog"
        with pytest.raises(GrblErrorReply, match="error:9 "):
            c.command("G1 X-5 F100")  # G-code is locked out while jogging
        clock.advance(5.0)
        st = c.status()
        assert st.state == "Idle" and st.mpos[0] == pytest.approx(-10.0)
        with pytest.raises(GrblErrorReply, match="error:15 .Travel exceeded"):
            c.command("$J=G53 X-600 F1000")  # beyond $130=500: ignored, no alarm
        assert c.status().state == "Idle" and fake.moves_started == 1
        with pytest.raises(GrblErrorReply, match="error:22"):
            c.command("$J=G91 X-1")  # a jog needs its own feed
        with pytest.raises(GrblErrorReply, match="error:16"):
            c.command("$J=G91 X-1 M8 F100")
        c.link.close()


def test_a_setting_sent_while_moving_is_refused_at_once_with_error_8():
    clock = ManualClock()
    with fake_device(clock=clock, time_scale=1.0) as fake:
        c = _unlocked(fake)
        c.command("G53 G1 X-100 F1000")  # frozen clock: it stays in Run
        assert c.status().state == "Run"
        for line in ("$110=5000", "$$", "$H", "$J=G91 X-1 F100"):
            with pytest.raises(GrblErrorReply, match="error:8 .Not idle"):
                c.command(line)
        c.command("$G")  # allowed in any state
        assert fake.settings[110] == 6000.0
        c.link.close()


def test_soft_limit_alarm_leaves_an_ok_that_arrives_after_ctrl_x():
    with fake_device() as fake:
        c = _unlocked(fake)
        with pytest.raises(GrblAlarm, match="ALARM:2 .Soft limit"):
            c.command("G53 G0 X-600")
        c.link.readline(0.5)  # [MSG:Reset to continue]
        c.realtime(b"\x18")
        lines = [c.link.readline(1.0) for _ in range(4)]
        assert lines == [b"ok", b"", b"Grbl 1.1h ['$' for help]", b"[MSG:'$H'|'$X' to unlock]"]
        c.link.close()


def test_motion_accelerates_and_brakes():
    clock = ManualClock()
    with fake_device(settings={120: 200.0}, clock=clock, time_scale=1.0) as fake:
        c = _unlocked(fake)
        c.command("G53 G1 X-100 F3000")  # 50 mm/s, 200 mm/s^2: 0.25 s and 6.25 mm to reach speed
        clock.advance(0.25)
        st = c.status()
        assert st.mpos[0] == pytest.approx(-6.25) and st.feed == pytest.approx(3000.0)
        clock.advance(1.75)  # 2.0 s: a move without acceleration would be over
        st = c.status()
        assert st.state == "Run" and st.mpos[0] == pytest.approx(-93.75)
        assert trapezoid_seconds(100.0, 50.0, 200.0) == pytest.approx(2.25)
        clock.advance(0.25)
        st = c.status()
        assert st.state == "Idle" and st.mpos[0] == pytest.approx(-100.0)
        c.link.close()


def test_feed_hold_brakes_in_hold_1_ignores_resume_then_holds_in_hold_0():
    clock = ManualClock()
    with fake_device(settings={120: 10.0}, clock=clock, time_scale=1.0) as fake:
        c = _unlocked(fake)
        c.command("G53 G1 X-200 F600")  # 10 mm/s, 10 mm/s^2: 1 s and 5 mm to stop
        clock.advance(5.0)
        assert c.status().mpos[0] == pytest.approx(-45.0)
        c.realtime(b"!")
        st = c.status()
        assert (st.state, st.substate) == ("Hold", 1)
        c.realtime(b"~")  # ignored while braking
        clock.advance(0.5)
        assert (c.status().state, c.status().substate) == ("Hold", 1)
        clock.advance(0.5)
        st = c.status()
        assert (st.state, st.substate) == ("Hold", 0) and st.mpos[0] == pytest.approx(-50.0)
        clock.advance(10.0)
        assert c.status().mpos[0] == pytest.approx(-50.0)  # still held: the early ~ was dropped
        c.realtime(b"~")
        clock.advance(30.0)
        st = c.status()
        assert st.state == "Idle" and st.mpos[0] == pytest.approx(-200.0)
        c.link.close()


def test_feed_hold_when_idle_is_hold_0():
    with fake_device() as fake:
        c = _unlocked(fake)
        c.realtime(b"!")
        st = c.status()
        assert (st.state, st.substate) == ("Hold", 0)
        c.realtime(b"~")
        assert c.status().state == "Idle"
        c.link.close()


def test_homing_takes_the_time_its_settings_give():
    clock = ManualClock()
    with fake_device(settings={23: 1}, carriage_mm=(-100.0, -250.0, -50.0), clock=clock, time_scale=1.0) as fake:
        c = connected(fake)
        # X homes towards - ($23 bit 0): its switch is at -500, 400 mm away; Y's 250 mm; Z's 50 mm
        seconds = homing_seconds([400.0, 250.0, 50.0], fake.settings)
        assert seconds == pytest.approx(61.28)  # Z: 52 mm at $25=500, X/Y: 402 mm; 2 x (1 mm at $24=25, 4 x 0.25 s)
        c.write_line("$H")
        for _ in range(5000):  # until the board has taken the line: time may pass then
            if fake.state == "Home":
                break
            time.sleep(0.001)
        clock.advance(seconds - 0.5)
        assert c.link.readline(0.2) is None  # still homing (and `?` goes unanswered)
        clock.advance(1.0)
        assert c.link.readline(1.0) == b"ok"
        assert c.status().mpos == (-499.0, -1.0, -1.0)  # X: -$130 + $27; Y, Z: -$27
        c.link.close()


def test_status_reports_carry_ov_and_accessory_fields():
    with fake_device() as fake:
        c = _unlocked(fake)
        c.command("M8")
        raws = [c.status().raw for _ in range(3)]
        assert any("|Ov:100,100,100|A:F" in r for r in raws), raws
        c.link.close()


def test_parser_accepts_ov_and_a_fields():
    st, _ = parse_status("<Run|MPos:-321.100,-98.613,-1.000|FS:3000,0|Ov:100,100,100|A:SF>")
    assert st.state == "Run" and st.mpos == (-321.1, -98.613, -1.0)
    assert st.fields["Ov"] == "100,100,100" and st.fields["A"] == "SF"

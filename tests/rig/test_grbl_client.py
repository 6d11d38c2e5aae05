"""The GRBL client against the fake GRBL 1.1 device behind a real pseudo-terminal."""

import time

import pytest
from rig_helpers import client_for, connected, fake_device

from torchrefl.errors import RigError
from torchrefl.rig.grbl import ControllerReset, GrblAlarm, GrblErrorReply, parse_status
from torchrefl.rig.link import NoReply


def test_handshake_settings_and_alarm_lock():
    with fake_device() as fake:
        c = connected(fake)
        assert c.banner == "Grbl 1.1h ['$' for help]" and c.version == "1.1h"
        # pyserial flushes input on open, so the power-up banner is gone: the client sent Ctrl-X
        assert b"\x18" in fake.received
        assert c.last_status.state == "Alarm"  # homing enabled: locked at power-up
        assert "[MSG:'$H'|'$X' to unlock]" in c.messages
        settings = c.read_settings()
        assert settings == {k: float(v) for k, v in fake.settings.items()}
        assert settings[130] == 500.0 and settings[22] == 1.0
        c.link.close()


def test_unlock_home_and_move_reach_position():
    with fake_device() as fake:
        c = connected(fake)
        with pytest.raises(GrblErrorReply, match="error:9 .G-code lock"):
            c.move_to({"X": -10.0}, 1000)
        c.unlock()
        assert "[MSG:Caution: Unlocked]" in c.messages
        st = c.home()
        assert st.state == "Idle" and st.mpos == (-1.0, -1.0, -1.0)  # GRBL: home minus $27 pull-off
        c.move_to({"X": -123.4, "Y": -56.7}, 3000)
        st = c.wait_idle()
        assert st.mpos == pytest.approx((-123.4, -56.7, -1.0), abs=1e-9)
        assert fake.mpos == pytest.approx([-123.4, -56.7, -1.0])
        assert "G21 G90 G53 G1 X-123.400 Y-56.700 F3000.0" in fake.lines
        c.move_to({"Y": -20.0}, rapid=True)
        assert c.wait_idle().mpos == pytest.approx((-123.4, -20.0, -1.0))
        c.link.close()


def test_work_position_reports_are_converted_with_wco():
    with fake_device(settings={10: 0}, wco=(10.0, -20.0, 0.5)) as fake:
        c = connected(fake)
        c.home()
        c.move_to({"X": -40.0, "Y": -30.0}, 3000)
        st = c.wait_idle()
        assert "WPos" in st.fields and "MPos" not in st.fields
        assert st.mpos == pytest.approx((-40.0, -30.0, -1.0))
        c.link.close()


def test_parse_status_documented_examples():
    st, wco = parse_status("<Idle|MPos:0.000,-10.000,5.000|FS:0,0>")
    assert st.state == "Idle" and st.mpos == (0.0, -10.0, 5.0) and wco is None
    st, wco = parse_status("<Hold:0|WPos:-2.500,0.000,11.000|FS:0,0|WCO:0.000,1.551,5.664>")
    assert st.state == "Hold" and st.substate == 0
    assert st.mpos == pytest.approx((-2.5, 1.551, 16.664))
    st, _ = parse_status("<Run|WPos:1.000,2.000,3.000|Bf:15,128|F:500>", wco=(1.0, 1.0, 1.0))
    assert st.mpos == (2.0, 3.0, 4.0) and st.feed == 500.0
    with pytest.raises(RigError, match="unknown machine state 'Busy'"):
        parse_status("<Busy|MPos:0,0,0>")


def test_timeout_names_port_and_command():
    with fake_device() as fake:
        c = connected(fake, home_s=0.3)
        fake.silence(after_line="$H")
        with pytest.raises(NoReply) as info:
            c.home()
        assert str(info.value) == f"no reply from {fake.path} within 0.3 s to '$H'"
        c.link.close()


def test_no_device_at_port_is_a_clear_error(tmp_path):
    c = client_for(type("F", (), {"path": str(tmp_path / "ttyNOPE")})())
    with pytest.raises(RigError, match="cannot open serial port .*ttyNOPE"):
        c.link.open()


def test_garbage_is_reported_and_the_client_recovers():
    with fake_device() as fake:
        c = connected(fake)
        fake.garbage_before("$$", b"\xff\xfe\x80\x81 noise\r\nhello there\r\n\x01\x02\r\n")
        settings = c.read_settings()  # the valid lines that follow still parse
        assert settings[131] == 300.0
        assert b"\xff\xfe\x80\x81 noise" in c.garbage
        assert b"hello there" in c.garbage and b"\x01\x02" in c.garbage
        c.unlock()  # and the next exchange works
        assert c.status().state == "Idle"
        c.link.close()


def test_error_reply_becomes_readable_rig_error():
    with fake_device() as fake:
        c = connected(fake)
        c.home()
        fake.error_on("G1", 22)
        with pytest.raises(GrblErrorReply) as info:
            c.move_to({"X": -10.0}, 1000)
        msg = str(info.value)
        assert info.value.code == 22 and "Undefined feed rate" in msg and "G1 X-10.000" in msg and fake.path in msg
        c.move_to({"X": -10.0}, 1000)  # the next command is fine
        assert c.wait_idle().mpos[0] == pytest.approx(-10.0)
        c.link.close()


def test_alarm_mid_move_then_reset_and_rehome():
    with fake_device() as fake:
        c = connected(fake)
        c.home()
        fake.alarm_during_move(fake.moves_started + 1, code=1)
        c.move_to({"X": -200.0}, 6000)
        with pytest.raises(GrblAlarm, match="ALARM:1 .Hard limit") as info:
            c.wait_idle()
        assert info.value.position_lost and c.alarm == 1
        assert fake.state == "Alarm" and -200.0 < fake.mpos[0] < -1.0  # stopped half-way
        c.soft_reset()  # critical alarm: only a reset is accepted
        assert c.status().state == "Alarm"
        c.home()
        assert c.status().mpos == (-1.0, -1.0, -1.0)
        c.link.close()


def test_feed_hold_and_resume():
    with fake_device(time_scale=0.05) as fake:
        c = connected(fake)
        c.home()
        c.move_to({"X": -101.0}, 600)  # 100 mm at 600 mm/min: 10 s simulated, 0.5 s here
        while c.status().mpos[0] > -2.0:  # under way
            pass
        c.feed_hold()
        st = c.status()
        while st.state == "Run":
            st = c.status()
        assert (st.state, st.substate) == ("Hold", 0)
        a = c.status().mpos
        time.sleep(0.05)
        assert c.status().mpos == a and -101.0 < a[0] < -1.0  # held: not moving
        c.resume()
        assert c.wait_idle().mpos[0] == pytest.approx(-101.0)
        c.link.close()


def test_soft_reset_during_motion_raises_alarm_3():
    with fake_device(time_scale=0.05) as fake:
        c = connected(fake)
        c.home()
        c.move_to({"X": -300.0}, 600)
        c.soft_reset()
        assert c.alarm == 3 and c.status().state == "Alarm"
        c.link.close()


def test_unrequested_banner_is_a_controller_reset():
    with fake_device() as fake:
        c = connected(fake)
        c.home()
        fake.reboot()
        with pytest.raises(ControllerReset, match="reset unexpectedly.*position is lost"):
            c.status()
        c.link.close()


def _moves(n):
    return [f"G1 X-{10 + i}.125 Y-{20 + (i % 7)}.5 F6000" for i in range(n)]


def test_streaming_keeps_within_the_receive_buffer():
    lines = _moves(40)
    assert sum(len(s) + 1 for s in lines) > 4 * 128
    with fake_device(planner_blocks=2, time_scale=0.05) as fake:
        c = connected(fake)
        c.home()
        before = len(fake.lines)
        assert c.stream(lines) == 40
        c.wait_idle()
        assert fake.overflow_bytes == 0 and fake.max_rx_used <= 127
        assert fake.lines[before:] == lines
        assert c.status().mpos[:2] == pytest.approx((-49.125, -24.5))
        c.link.close()


def test_blasting_without_counting_overflows_the_fake():
    """Control for the test above: the fake really enforces its 128-byte buffer."""
    lines = _moves(40)
    with fake_device(planner_blocks=2, time_scale=0.05) as fake:
        c = connected(fake)
        c.home()
        before = len(fake.lines)
        c.link.write("".join(s + "\n" for s in lines).encode())
        deadline = time.monotonic() + 5
        while fake.moves_started < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert fake.overflow_bytes > 0
        c.soft_reset()
        assert len(fake.lines) - before < 40
        c.link.close()


def test_streaming_stops_at_the_first_error():
    lines = _moves(12)
    with fake_device(planner_blocks=2) as fake:
        c = connected(fake)
        c.home()
        fake.error_on("X-15.125", 33)
        with pytest.raises(GrblErrorReply, match=r"X-15.125.*error:33 .*Motion command target is invalid"):
            c.stream(lines)
        sent = [s for s in fake.lines if s.startswith("G1")]
        assert "G1 X-15.125 Y-25.5 F6000" in sent and len(sent) < 12
        c.link.close()


def test_garbled_status_report_is_retried_and_counted():
    notes = []
    with fake_device() as fake:
        c = connected(fake, log=notes.append)
        c.home()
        c.move_to({"X": -50.0}, 3000)
        fake.garble_reports(2)  # as seen: '-98:613' in the MPos field
        st = c.wait_idle()
        assert st.mpos[0] == pytest.approx(-50.0)
        assert c.status_retried == 2
        assert sum("status query retried" in n for n in notes) == 2
        assert any("-" in g.decode() and ":" in g.decode() for g in c.garbage)
        c.link.close()


def test_board_that_stops_answering_status_is_held_then_an_error():
    with fake_device(time_scale=0.05) as fake:
        c = connected(fake, reply_s=0.2, status_retries=2)
        c.home()
        c.move_to({"X": -400.0}, 600)
        fake.drop_reports(3)
        with pytest.raises(NoReply, match=r"status query '\?' \(3 queries.*sent a feed hold '!'"):
            c.status()
        assert c.status_retried == 2
        for _ in range(1000):  # until the board has read the '!'
            if b"!" in fake.received:
                break
            time.sleep(0.001)
        assert fake.received.count(b"!") == 1 and fake.machine_state().startswith("Hold")
        c.link.close()


def test_a_missing_status_report_is_retried():
    with fake_device() as fake:
        c = connected(fake, reply_s=0.2)
        fake.drop_reports(1)
        assert c.status().state == "Alarm" and c.status_retried == 1
        c.link.close()


def test_feed_hold_waits_for_hold_0_so_an_immediate_resume_works():
    # 10 mm/s braking at 10 mm/s^2: Hold:1 lasts 1 s simulated (0.2 s here); a `~` then is ignored
    with fake_device(settings={120: 10.0}, time_scale=0.2) as fake:
        c = connected(fake, move_s=20.0)
        c.home()
        c.move_to({"X": -61.0}, 600)
        while c.status().mpos[0] > -20.0:
            pass
        st = c.feed_hold()
        assert (st.state, st.substate) == ("Hold", 0)
        held = st.mpos[0]
        st = c.resume()
        assert st.state == "Run"
        st = c.wait_idle()
        assert st.mpos[0] == pytest.approx(-61.0) and -61.0 < held < -20.0
        c.link.close()


def test_homing_timeout_is_computed_from_the_settings_with_progress_notes():
    from torchrefl.rig.grbl_homing import homing_timeout_s

    notes = []
    with fake_device(time_scale=0.02, carriage_mm=(-450.0, -250.0, -150.0)) as fake:
        c = connected(fake, home_s=None, progress_s=0.1)
        assert c.homing_timeout() == pytest.approx(homing_timeout_s(c.settings))
        assert c.homing_timeout() > 150.0  # 500 mm at $25=500 mm/min can outlast 90 s
        st = c.home(progress=notes.append)  # about 86 s simulated, 1.7 s here
        assert st.mpos == (-1.0, -1.0, -1.0)
        assert "computed from $130-$132" in notes[0]
        assert any("homing... " in n for n in notes[1:])
        c.link.close()

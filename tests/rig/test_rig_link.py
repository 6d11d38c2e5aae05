"""SerialLink over pyserial URLs (loop://) and the GRBL code tables."""

import pytest

from torchrefl.errors import RigError
from torchrefl.rig.grbl_codes import ALARMS, ERRORS, alarm_message, error_message
from torchrefl.rig.link import PortLost, SerialLink


def test_loop_url_lines_and_timeout():
    with SerialLink("loop://") as link:
        link.write(b"ok\r\nerror:9\r\npartial")
        assert link.readline(0.5) == b"ok"
        assert link.readline(0.5) == b"error:9"
        assert link.readline(0.05) is None  # no newline yet
        link.write(b" line\n\xff\xfe\n")
        assert link.readline(0.5) == b"partial line"
        assert link.readline(0.5) == b"\xff\xfe"  # raw bytes: decoding is the client's job


def test_open_failure_and_closed_port():
    with pytest.raises(RigError, match="cannot open serial port /nonexistent/ttyX at 115200 baud"):
        SerialLink("/nonexistent/ttyX").open()
    link = SerialLink("loop://")
    with pytest.raises(PortLost, match="serial port loop:// is not open"):
        link.write(b"?")
    with pytest.raises(PortLost, match="did not come back within 0.1 s"):
        SerialLink("/nonexistent/ttyX").reopen(0.1)


def test_code_tables_follow_grbl_csv():
    # gnea/grbl doc/csv/error_codes_en_US.csv and alarm_codes_en_US.csv (v1.1)
    assert sorted(ERRORS) == list(range(1, 18)) + list(range(20, 39))
    assert sorted(ALARMS) == list(range(1, 10))
    assert error_message(9) == "error:9 (G-code lock): G-code commands are locked out during alarm or jog state."
    assert error_message(22).startswith("error:22 (Undefined feed rate)")
    assert alarm_message(2).startswith("ALARM:2 (Soft limit): Soft limit alarm.")
    assert "unknown" in error_message(99) and "unknown" in alarm_message(42)


class VanishingPort:
    """A pyserial port whose device has gone: every operation raises what that call raises then (pyserial's
    flush is termios.tcdrain, which raises termios.error, not an OSError; reads raise SerialException)."""

    def __init__(self, error):
        self.error = error

    def write(self, data):
        return len(data)

    def flush(self):
        raise self.error

    @property
    def in_waiting(self):
        raise self.error

    def read(self, n):
        raise self.error

    def close(self):
        raise self.error


@pytest.mark.parametrize("kind", ["termios", "oserror", "serial"])
def test_a_port_that_vanishes_mid_call_is_a_port_lost_whatever_it_raises(kind):
    import termios

    import serial

    error = {
        "termios": termios.error(5, "Input/output error"),
        "oserror": OSError(5, "Input/output error"),
        "serial": serial.SerialException("device reports readiness to read but returned no data"),
    }[kind]
    for call in (lambda link: link.write(b"?"), lambda link: link.readline(0.05)):
        link = SerialLink("loop://")
        link._port = VanishingPort(error)
        with pytest.raises(PortLost, match="serial port loop:// failed during"):
            call(link)
        assert not link.is_open  # closed, although closing raised too

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

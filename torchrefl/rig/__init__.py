"""The capture rig: a GRBL 1.1 light gantry driven over a serial port, a camera trigger, and a
resumable capture-plan runner that writes a `cylindrical_scan` capture folder.

Modules: link (serial line I/O), grbl_codes (error/alarm tables), grbl (the GRBL client), grbl_status
(status reports), grbl_stream (character-counting streaming), grbl_homing (how long `$H` takes),
board_check (the board's `$$` against the rig config), model (light grid <-> axis coordinates, soft
limits, light switch), camera (external command or simulated), plan (ordering), runner (the
loss-free runner), settings (configs/rig.yaml), __main__ (the CLI); fake_grbl (a simulated Grbl 1.1h
board behind a pseudo-terminal, for tests and dry runs) with fake_port, fake_settings, fake_gcode,
fake_motion and fake_commands.
"""

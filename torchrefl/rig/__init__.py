"""The capture rig: a GRBL 1.1 light gantry driven over a serial port, a camera trigger, and a
resumable capture-plan runner that writes a `cylindrical_scan` capture folder.

Modules: link (serial line I/O), grbl_codes (error/alarm tables), grbl (the GRBL client), model
(light grid <-> axis coordinates, soft limits, light switch), camera (external command or simulated),
plan (ordering and the loss-free runner), settings (configs/rig.yaml), fake_grbl (a simulated
GRBL 1.1 device behind a pseudo-terminal, for tests and dry runs), __main__ (the CLI).
"""

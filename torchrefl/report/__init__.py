"""Outputs: metrics, maps, and a finished run read back (load_run)."""

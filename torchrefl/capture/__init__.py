"""Capture kinds: each loader reads a capture folder into one Capture (Surface + Observations + truth)."""

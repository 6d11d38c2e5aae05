"""Capture kinds: each loader turns a capture on disk (or a synthetic scene) into Surface + Observations."""

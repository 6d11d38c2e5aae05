"""Outputs: metrics, maps, plots, stage timing and progress."""

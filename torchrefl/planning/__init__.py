"""Automatic light-position selection (dissertation Ch.2)."""

from torchrefl.planning.light_selection import SelectionResult, select_for_scan  # noqa: E402

__all__ = ["SelectionResult", "select_for_scan"]

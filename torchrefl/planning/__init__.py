"""Automatic light-position selection (dissertation Ch.2)."""

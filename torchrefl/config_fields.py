"""The one way a config field is declared: a default, a one-line doc, optional choices and range."""

from __future__ import annotations

from dataclasses import field


def opt(default, doc: str, choices: tuple = (), low: float | None = None, high: float | None = None):
    """A config field with a default, a one-line doc and optional choices/range."""
    meta = {"doc": doc, "choices": choices, "low": low, "high": high}
    if isinstance(default, (list, dict)):
        return field(default_factory=lambda d=default: list(d) if isinstance(d, list) else dict(d), metadata=meta)
    return field(default=default, metadata=meta)

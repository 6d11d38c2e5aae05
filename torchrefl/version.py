"""The torchrefl version (one place; torchrefl/__init__ re-exports it)."""

__version__ = "0.1.0"

"""Test-only reference code written apart from torchrefl (it imports nothing from torchrefl)."""

"""Core: the texel Surface, Observations, the BRDF, ray casting, point-light geometry, texel-grid operations.

Imports nothing from the other torchrefl packages: every stage builds on it.
"""

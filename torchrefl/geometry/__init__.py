"""Geometry: range-image preprocessing, the texel Surface, meshes."""

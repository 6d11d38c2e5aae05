"""Synthetic scenes: objects with known reflectance, rendered (with interreflection) into capture folders the
loaders read."""

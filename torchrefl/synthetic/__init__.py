"""Synthetic scenes: objects with known reflectance, rendered (with interreflection) into capture folders the
loaders read."""

from torchrefl.synthetic.capture import synthetic_capture  # noqa: E402
from torchrefl.synthetic.objects import make_object  # noqa: E402
from torchrefl.synthetic.scan import SyntheticScan  # noqa: E402

__all__ = ["SyntheticScan", "make_object", "synthetic_capture"]

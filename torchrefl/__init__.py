"""torchrefl: dense reflectance estimation (Pd, Ps, sigma per texel) by inverse rendering.

See README.md for the command line and DESIGN notes; the data flow is
config -> capture (Surface + Observations) -> precompute -> initialise -> fit -> outputs.
"""

__version__ = "0.1.0"

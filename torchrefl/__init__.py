"""torchrefl: dense reflectance estimation (Pd, Ps, sigma per texel) by inverse rendering.

    import torchrefl
    run = torchrefl.fit("configs/default.yaml", ["output.dir=outputs/x"])   # fit a config -> RunResult
    run = torchrefl.load_run("outputs/x")                                     # a finished run
    cfg = torchrefl.load_config("configs/default.yaml")                        # the typed Config

The data flow: config -> capture (Surface + Observations) -> transport level -> fit -> outputs.
"""

from torchrefl.config import Config, load_config  # noqa: E402
from torchrefl.errors import TorchReflError  # noqa: E402
from torchrefl.report.run_result import RunResult, load_run  # noqa: E402
from torchrefl.run import fit  # noqa: E402
from torchrefl.version import __version__  # noqa: E402

__all__ = ["Config", "RunResult", "TorchReflError", "__version__", "fit", "load_config", "load_run"]

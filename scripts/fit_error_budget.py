"""Where a finished photon-level fit's Pd error comes from, on a synthetic capture (truth.npz beside it).

For the run's own lobes (Ps, sigma), per truth region, the Pd that the local model plus an indirect estimate gives
in closed form (least squares over the run's fitted observations) against the truth, with the indirect light of:

1. the photon level at the run's parameters (what the fit itself saw; matching the run's Pd says it converged),
2. the photon level at the TRUE parameters (the cost of the other texels' parameter errors is 1 minus 2),
3. the capture's own indirect light (noise-free render minus direct-only render; the cost of photon noise is 2 - 3),

and the held-out images' mean |diff| (8-bit, as in metrics.json) for the run, for the truth with the level's
indirect light and for the truth with the true one (the floor that sensor noise and quantisation leave).

    python scripts/fit_error_budget.py configs/fold.yaml <run>/capture <run>
    python scripts/fit_error_budget.py --tiny      # a tiny fold fitted with the photon level first (the test's mode)

Slow: two renders of the capture's lights (scripts/photon_noise_at_truth.py) and two photon caches.
docs/results/fold.md ("Where the rest of the error comes from") has the fold's numbers.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from torchrefl.capture.base import loader_for
from torchrefl.config import load_config
from torchrefl.core.brdf import specular_lobe
from torchrefl.fit.emitter_fill import nearest_fitted
from torchrefl.fit.pipeline import level_inputs
from torchrefl.report.metrics import image_difference
from torchrefl.transport.levels.auto import named_level, prepare
from torchrefl.transport.photon_cache import indirect_radiance

sys.path.insert(0, str(Path(__file__).parent))
from photon_noise_at_truth import renders  # noqa: E402
from tiny_mode import FOLD, tiny_run  # noqa: E402


def closed_form_pd(terms, target, mask, ps, sigma) -> torch.Tensor:
    """(T, 3) least-squares Pd of target (P, T, 3) over mask (P, T) with the lobe (ps, sigma) held."""
    a = terms.diffuse.double() * mask.double()[..., None]
    lobe = specular_lobe(terms.brdf, terms.theta_h.double(), sigma.double()[None])[..., None]
    spec = lobe * terms.specular.double() * ps.double()[None]
    return (a * (target - spec)).sum(0) / (a * a).sum(0).clamp_min(1e-30)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("config", nargs="?", help="the synthetic config that wrote the capture")
    ap.add_argument("capture", nargs="?", help="the capture folder (cylindrical_scan with truth.npz)")
    ap.add_argument("run", nargs="?", help="a finished photon-level run on that capture (its params.npz, config.yaml)")
    ap.add_argument("--tiny", action="store_true", help="fit the tiny fold (scripts/tiny_mode.py) and analyse it")
    args = ap.parse_args(argv)
    if args.tiny and args.run is None:
        run = tiny_run(Path(tempfile.mkdtemp(prefix="fit_error_budget_")) / "run")
        args.config, args.capture, args.run = str(FOLD), str(run / "capture"), str(run)
    if args.run is None:
        ap.error("give CONFIG CAPTURE RUN, or --tiny")
    over = [
        "capture.kind=cylindrical_scan",
        f"capture.path={args.capture}",
        "fit.model=photon",
        "output.progress=false",
    ]
    cfg = load_config(f"{args.run}/config.yaml", over)
    cap = loader_for(cfg.capture.kind).load(args.capture, cfg, lambda m: None)
    s = cap.surface
    grid = np.load(f"{args.run}/params.npz")
    run = {k: s.from_grid(grid[k]).double() for k in ("pd", "ps", "sigma")}
    estimated = s.from_grid(grid["mask"] & (grid["coverage"] > 0)).bool()
    measured = s.from_grid(grid["n_specular"] >= 2).bool() & estimated
    truth = {k: cap.truth[k].double() for k in ("pd", "ps", "sigma")}
    region = s.from_grid(np.load(f"{args.capture}/truth.npz")["region"]).long()
    true_indirect = renders(cfg, args.capture, s, True, 100) - renders(cfg, args.capture, s, False, 100)

    inputs, _ = level_inputs(cfg, cap, lambda m: None)
    level = named_level(inputs)
    prepare(level)
    level.use_emitters(nearest_fitted(s.positions, estimated))

    def level_indirect(p):
        pd, ps, sg = (p[k].float() for k in ("pd", "ps", "sigma"))
        with torch.no_grad():
            return indirect_radiance(
                level.refresher.cache(pd, ps, sg, refresh=0), inputs.obs.kappa, pd, ps, sg
            ).double()

    at_run, at_truth = level_indirect(run), level_indirect(truth)
    intensity = cap.obs.intensity.double()

    def row(name, pd):
        err = pd - truth["pd"]
        rel = err.mean(-1) / truth["pd"].mean(-1)
        rms = lambda k: float(err[k].square().mean().sqrt())
        cells = [f"{rms(estimated):.4f}", f"{float((rel[measured].abs() < 0.02).double().mean()):.1%}"]
        for r in region[estimated].unique().tolist():
            k = estimated & (region == r)
            cells.append(f"{rms(k):.4f} / {float(rel[k].median()):+.4f}")
        print(f"| {name} | " + " | ".join(cells) + " |")

    regions = region[estimated].unique().tolist()
    print(
        "| Pd from | pd_rmse | measured within 2 % | "
        + " | ".join(f"region {r} rms / median rel." for r in regions)
        + " |"
    )
    print("|---" * (3 + len(regions)) + "|")
    row("the run", run["pd"])
    for name, ind in (
        ("level at the run's parameters", at_run),
        ("level at the truth", at_truth),
        ("true indirect", true_indirect),
    ):
        row(
            f"closed form, run's lobes, {name}",
            closed_form_pd(inputs.terms, intensity - ind, inputs.fit_mask, run["ps"], run["sigma"]),
        )

    local = inputs.local_predict()
    direct = {
        n: local(*(p[k].float() for k in ("pd", "ps", "sigma"))).double() for n, p in (("run", run), ("truth", truth))
    }
    held = inputs.eval_mask
    held_out_abs = lambda pred: image_difference(pred, intensity, held)["mean_abs_diff_8bit"]
    if held.any():
        print(
            f"held-out mean |diff| (8-bit): run {held_out_abs(direct['run'] + at_run):.3f}; truth with the "
            f"level's indirect {held_out_abs(direct['truth'] + at_truth):.3f}; truth with the true "
            f"indirect {held_out_abs(direct['truth'] + true_indirect):.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

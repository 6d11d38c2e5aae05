"""How much of a synthetic capture's per-texel Pd error the photon level's cache noise explains.

For a capture folder written by a synthetic config (its truth.npz beside the textures), at the TRUE parameters:

1. the capture's own indirect light: a noise-free render of the same lights minus a direct-only render;
2. the photon level's indirect light (its cache traced at the truth) for each setting given, its rms error
   against (1) and the rms difference between two photon seeds (the cache's noise);
3. per-texel local fits started at the truth on the capture minus each indirect estimate (the true one first),
   and the share of texels with at least two T_spec observations whose Pd lands within 2 % of the truth.

    python scripts/photon_noise_at_truth.py configs/fold.yaml <run>/capture \
        --setting photon.photons_per_light=400000,photon.smoothing=2,photon.specular_smoothing=1 --setting ""

Each --setting is a comma-separated list of overrides (empty: the defaults). The renders use the config's
synthetic.indirect_samples, so their own Monte Carlo noise enters the "true" row (0.18 DN rms at the fold's 160 paths
and 3 x 3 sub-samples; on a 256 x 225 fold at 64 paths and 2 x 2 it lowers that row below the defaults' own).
docs/results/fold.md ("Photon noise") has the fold's numbers. Slow: two renders of the capture's lights and two
caches per setting.

    python scripts/photon_noise_at_truth.py --tiny [configs/fold.yaml <tiny run>/capture]   # the test's mode
--tiny renders and traces at scripts/tiny_mode.py's sizes, on a tiny fold it fits first when no capture is given.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch
import yaml

from torchrefl.capture.base import loader_for
from torchrefl.config import load_config
from torchrefl.core.observation_classes import T_SPEC
from torchrefl.fit.pipeline import level_inputs
from torchrefl.synthetic.scan import SyntheticScan
from torchrefl.transport.levels.auto import named_level, prepare
from torchrefl.transport.photon_cache import indirect_radiance

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import FOLD, TINY, tiny_run  # noqa: E402


def renders(cfg, capture_path: str, surface, indirect: bool, seed: int) -> torch.Tensor:
    """(P, T, 3) noise-free sensor values of the capture's lights, with or without interreflection."""
    positions = np.array([e["position_mm"] for e in yaml.safe_load(open(f"{capture_path}/scan.yaml"))["lights"]])
    syn = cfg.synthetic if indirect else dataclasses.replace(cfg.synthetic, indirect_samples=0)
    scan = SyntheticScan(syn, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa, threads=cfg.threads)
    scan.path_seed = seed  # not the capture's own paths
    images = scan.radiance_images(positions)
    return torch.stack([surface.from_grid(img) for img in images]).double()


def local_fit(inputs, target: torch.Tensor, truth) -> torch.Tensor:
    """Pd (T, 3) of per-texel local fits of target (P, T, 3) started at the truth (LBFGS on log parameters, bounded to
    [e^-9, e] so that a noisy target cannot run off)."""
    local, fit = inputs.local_predict(), inputs.fit_mask
    lp, ls, lg = (torch.log(x.clone()).requires_grad_() for x in (truth[0], truth[1][:, :1], truth[2]))
    opt = torch.optim.LBFGS([lp, ls, lg], max_iter=300, line_search_fn="strong_wolfe", tolerance_grad=1e-12)

    def closure():
        opt.zero_grad()
        pd, ps, sigma = (x.clamp(-9.0, 1.0).exp() for x in (lp, ls, lg))
        pred = local(pd.float(), ps.expand(-1, 3).float(), sigma.float()).double()
        loss = (((pred - target) ** 2).sum(-1) * fit).sum() * 255**2 / fit.sum()
        loss.backward()
        return loss

    for _ in range(3):
        opt.step(closure)
    return lp.detach().clamp(-9.0, 1.0).exp()


def local_fit_within(inputs, target, truth, measured) -> float:
    """Share of `measured` texels whose Pd, fitted per texel by the local model from the truth, is within 2 %."""
    pd0 = truth[0]
    rel = (local_fit(inputs, target, truth) - pd0).mean(-1) / pd0.mean(-1)
    return float((rel[measured].abs() < 0.02).double().mean())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("config", nargs="?", help="the synthetic config that wrote the capture (its synthetic.* block)")
    ap.add_argument("capture", nargs="?", help="the capture folder (cylindrical_scan with truth.npz)")
    ap.add_argument("--setting", action="append", default=[], help="comma-separated overrides; repeatable")
    ap.add_argument("--tiny", action="store_true", help="scripts/tiny_mode.py's sizes (a tiny fold if no capture)")
    args = ap.parse_args(argv)
    if args.tiny and args.capture is None:
        run = tiny_run(Path(tempfile.mkdtemp(prefix="photon_noise_")) / "run", model="local")
        args.config, args.capture = str(FOLD), str(run / "capture")
    if args.capture is None:
        ap.error("give CONFIG CAPTURE, or --tiny")
    base = (TINY if args.tiny else []) + ["capture.kind=cylindrical_scan", f"capture.path={args.capture}"]
    base += ["fit.model=photon"]
    base.append("output.progress=false")
    cfg = load_config(args.config, base)
    cap = loader_for(cfg.capture.kind).load(args.capture, cfg, lambda m: None)
    s = cap.surface
    truth = tuple(cap.truth[k].double() for k in ("pd", "ps", "sigma"))
    true_indirect = renders(cfg, args.capture, s, True, 100) - renders(cfg, args.capture, s, False, 100)
    intensity = cap.obs.intensity.double()
    inputs, _ = level_inputs(cfg, cap, lambda m: None)
    keep = inputs.fit_mask
    rms = lambda x: float((x.mean(-1)[keep] ** 2).mean().sqrt() * 255)
    rows = [("true indirect light", true_indirect, None, None)]
    for setting in args.setting or [""]:
        over = [o for o in setting.split(",") if o]
        c = load_config(args.config, base + over)
        inputs, _ = level_inputs(c, cap, lambda m: None)
        level = named_level(inputs)
        prepare(level)
        level.refresher.emitter_source = level.radiosity.emitter_source = None  # every texel emits its truth
        pd, ps, sg = (x.float() for x in truth)
        with torch.no_grad():
            est = [
                indirect_radiance(level.refresher.cache(pd, ps, sg, refresh=r), inputs.obs.kappa, pd, ps, sg).double()
                for r in (0, 1)
            ]
        rows.append((setting or "defaults", est[0], rms(est[0] - true_indirect), rms(est[0] - est[1]) / 2**0.5))
    inputs, _ = level_inputs(cfg, cap, lambda m: None)  # the fits' observations: the config's own
    measured = ((inputs.classes == T_SPEC) & inputs.fit_mask).sum(0) >= 2
    print(f"{int(measured.sum())} texels with two T_spec observations; true indirect light {rms(true_indirect):.2f} DN")
    print("indirect light removed | rms error vs the true one (DN) | seed-to-seed noise (DN) | within 2 %")
    for name, ind, err, noise in rows:
        share = local_fit_within(inputs, intensity - ind, truth, measured)
        e = "-" if err is None else f"{err:.2f}"
        n = "-" if noise is None else f"{noise:.2f}"
        print(f"{name} | {e} | {n} | {share:.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

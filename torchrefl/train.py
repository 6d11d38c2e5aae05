"""python -m torchrefl.train CONFIG [dotted.key=value ...]

Runs the whole pipeline on one config: capture -> (light selection) -> precompute ->
initialise (closed forms, interpolation) -> fit -> outputs. See README.md for the outputs.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from torchrefl import __version__
from torchrefl.config import Config, describe, dump_config, load_config, resolve_path
from torchrefl.errors import ConfigError, TorchReflError
from torchrefl.fit.pipeline import fit_capture
from torchrefl.report.maps import write_light_maps, write_parameter_maps
from torchrefl.report.metrics import ground_truth_errors, image_difference
from torchrefl.report.stages import Stages, bar


class RunLog:
    """Writes timestamped lines to log.txt and to stderr."""

    def __init__(self, path: Path, quiet: bool = False):
        self.path = path
        self.quiet = quiet
        self.start = time.perf_counter()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(path, "w")

    def __call__(self, msg: str) -> None:
        line = f"[{time.perf_counter() - self.start:7.2f}s] {msg}"
        self._fh.write(line + "\n")
        self._fh.flush()
        if not self.quiet:
            print(line, file=sys.stderr)

    def close(self):
        self._fh.close()


def _device(cfg: Config) -> torch.device:
    if cfg.device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if cfg.device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device: 'cuda' requested but torch sees no CUDA device (use cpu or auto)")
    return torch.device(cfg.device)


def load_capture(cfg: Config, out: Path, stages: Stages, log) -> dict:
    """Capture stage: returns surface, obs, truth, stats, selection (dict)."""
    dtype = torch.float64 if cfg.dtype == "float64" else torch.float32
    kind = cfg.capture.kind
    result = {"selection": None, "truth": None}
    if kind == "photometric_stereo":
        from torchrefl.capture.photometric_stereo import load_photometric_stereo

        with stages.stage("capture"):
            surface, obs, stats = load_photometric_stereo(
                resolve_path(cfg, cfg.capture.path), saturation_level=cfg.capture.saturation_level,
                kappa=tuple(cfg.capture.kappa), light_subset=cfg.capture.light_subset, dtype=dtype,
                threads=cfg.threads)
        result.update(surface=surface, obs=obs, stats=stats)
        return result

    from torchrefl.capture.cylindrical_scan import load_scan_geometry, load_scan_observations, load_truth

    scan = None
    if kind == "synthetic_cylindrical":
        from torchrefl.capture.synthetic_scan import SyntheticScan

        with stages.stage("synthetic scan"):
            scan = SyntheticScan(cfg.synthetic, cfg.selection.grid, seed=cfg.seed, kappa=cfg.capture.kappa,
                                 threads=cfg.threads)
            folder = scan.write_geometry(out / "capture")
        log(f"synthetic {cfg.synthetic.object} written to {folder}")
    else:
        folder = resolve_path(cfg, cfg.capture.path)
    with stages.stage("geometry"):
        geom = load_scan_geometry(folder, median_size=cfg.geometry.median_size, fit_window=cfg.geometry.fit_window,
                                  noise_tolerance=cfg.geometry.noise_tolerance,
                                  threads=cfg.threads, dtype=dtype)
    log(f"surface: {geom.surface.num_texels} texels on a {geom.surface.grid_shape} grid, "
        f"{len(geom.surface.mesh_faces)} triangles")
    if scan is not None:
        candidates = scan.candidate_positions()
        positions = candidates
        if cfg.selection.enabled:
            from torchrefl.planning import plot_coverage, select_for_scan

            with stages.stage("light selection"):
                sel = select_for_scan(geom, candidates, cfg.selection, cfg.reflectance, cfg.geometry.shadow_offset_mm)
                positions = candidates[sel.chosen]
                (out / "selection").mkdir(parents=True, exist_ok=True)
                plot_coverage(sel, out / "selection" / "coverage.png")
                (out / "selection" / "selection.json").write_text(json.dumps(sel.to_json(), indent=2))
            result["selection"] = sel
            t = sel.table()
            log(f"light selection: {t['lights_selected']} of {t['candidates']} lights ({t['lights_for_diffuse']} for diffuse); "
                f"diffuse coverage {t['diffuse_coverage']:.1%} (all: {t['diffuse_coverage_all_candidates']:.1%}), "
                f"specular {t['specular_coverage']:.1%} (all: {t['specular_coverage_all_candidates']:.1%})")
        with stages.stage("render textures"):
            with bar(len(positions), "render", cfg.output.progress, unit="image") as pb:
                scan.write_textures(folder, positions, progress=pb)
    with stages.stage("observations"):
        obs, stats = load_scan_observations(
            geom, light_subset=cfg.capture.light_subset, saturation_level=cfg.capture.saturation_level,
            shadow_offset=cfg.geometry.shadow_offset_mm, threads=cfg.threads, dtype=dtype,
            edge_width=cfg.geometry.edge_width, crease_angle_deg=cfg.geometry.crease_angle_deg)
    if stats["crease_texels_excluded"]:
        log(f"geometry: {stats['crease_texels_excluded']} texels on creases sharper than "
            f"{cfg.geometry.crease_angle_deg:g} deg (mixed pixels) are not fitted")
    result.update(surface=geom.surface, obs=obs, stats=stats, truth=load_truth(folder, geom.surface))
    return result


def write_outputs(cfg: Config, out: Path, cap: dict, res: dict, stages: Stages, log) -> dict:
    surface, obs = cap["surface"], cap["obs"]
    mask_t = res["estimated"]
    mask = surface.to_grid(mask_t.numpy(), fill=False)
    grid = lambda x, fill=0.0: surface.to_grid(x, fill=fill)
    with stages.stage("outputs"):
        np.savez_compressed(
            out / "params.npz",
            pd=grid(res["pd"].float()), ps=grid(res["ps"].float()), sigma=grid(res["sigma"].float()), mask=mask,
            brdf=np.array(cfg.reflectance.brdf), positions=grid(surface.positions.float()),
            normals=grid(surface.normals.float()), coverage=grid(res["coverage"]),
            n_diffuse=grid(res["counts"]["T_diff"].to(torch.int16)), n_specular=grid(res["counts"]["T_spec"].to(torch.int16)),
            kappa=obs.kappa.numpy(), units=np.array(surface.units),
            diffuse=np.array(res["diffuse"]["model"]), minnaert_k=np.array(res["diffuse"]["k"]),
        )
        metrics = {
            "version": __version__,
            "model": res["model"],
            "model_reason": res["model_reason"],
            "model_numbers": res["model_numbers"],
            **({"photon": res["photon"]} if res.get("photon") else {}),
            "brdf": cfg.reflectance.brdf,
            "diffuse": {**res["diffuse"], **({"k_true": cap["truth"]["minnaert_k"]} if cap.get("truth") else {})},
            "capture": {"kind": cfg.capture.kind, **{k: v for k, v in cap["stats"].items() if isinstance(v, (int, float, str))}},
            "texels": surface.num_texels, "lights": obs.num_lights,
            "holdout_lights": list(cfg.fit.holdout),
            "rerender": image_difference(res["pred"], obs.intensity, res["fit_mask"]),
            "coverage": {
                "pd_closed_form": int(res["init"].pd_from_diffuse.sum()),
                "spec_closed_form": int(res["init"].spec_closed_form.sum()),
                "spec_known": int(res["init"].known.sum()),
                "estimated": int(mask_t.sum()),
            },
            "fit": {"optimizer": cfg.fit.optimizer, "loss_first": res["history"][0], "loss_last": res["history"][-1],
                    "evaluations": len(res["history"])},
            "device": str(_device(cfg)), "dtype": cfg.dtype,
        }
        if cfg.fit.holdout:
            metrics["holdout"] = image_difference(res["pred"], obs.intensity, res["eval_mask"])
        if cap.get("truth") is not None:
            spec2 = res["n_spec"] >= 2
            metrics["ground_truth"] = ground_truth_errors(res["pd"], res["ps"], res["sigma"], cap["truth"], mask_t, spec2)
        if cap.get("selection") is not None:
            metrics["selection"] = cap["selection"].table()
        maps = out / "maps"
        metrics["maps"] = write_parameter_maps(maps, mask, grid(res["pd"].double().numpy()), grid(res["ps"].double().numpy()),
                                               grid(res["sigma"].double().numpy()), grid(res["coverage"].numpy()),
                                               cfg.reflectance.sigma_max)
        k = min(cfg.output.map_lights, obs.num_lights)
        for p in np.linspace(0, obs.num_lights - 1, k).round().astype(int) if k else []:
            shown = surface.to_grid(obs.valid[p].numpy(), fill=False)
            write_light_maps(maps, f"light_{p:03d}", grid(obs.intensity[p].double().numpy()),
                             grid(res["pred"][p].double().numpy()), shown)
    metrics["timing_s"] = {k: round(v, 3) for k, v in stages.timing.items()}
    metrics["timing_s"]["total"] = round(stages.total(), 3)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics


def summary_table(metrics: dict) -> str:
    rows = [("stage", "seconds")] + [(k, f"{v:.2f}") for k, v in metrics["timing_s"].items()]
    lines = ["", "== torchrefl summary =="]
    w = max(len(r[0]) for r in rows)
    lines += [f"  {a:<{w}}  {b:>8}" for a, b in rows]
    fmt = lambda d: ", ".join(f"{k} {v:.4g}" for k, v in d.items() if isinstance(v, float))
    lines.append(f"  texels {metrics['texels']}, lights {metrics['lights']}, model {metrics['model']}, brdf {metrics['brdf']}")
    d = metrics.get("diffuse") or {}
    if d.get("model", "lambert") != "lambert":
        lines.append(f"  diffuse: {d['model']} k {d['k']:.4f} ({'fitted' if d.get('fitted') else 'reflectance.minnaert_k'})")
    lines.append(f"  re-render (fitted): {fmt(metrics['rerender'])}")
    if "holdout" in metrics:
        lines.append(f"  held-out lights:    {fmt(metrics['holdout'])}")
    if "ground_truth" in metrics:
        lines.append(f"  ground truth:       {fmt(metrics['ground_truth'])}")
    if "selection" in metrics:
        s = metrics["selection"]
        lines.append(f"  selection: {s['lights_selected']} lights, diffuse {s['diffuse_coverage']:.1%}, specular {s['specular_coverage']:.1%}")
    return "\n".join(lines)


def run(cfg: Config, quiet: bool = False) -> dict:
    """Run the pipeline for a loaded config; returns the metrics dict."""
    out = Path(cfg.output.dir)
    out.mkdir(parents=True, exist_ok=True)
    dump_config(cfg, out / "config.yaml")
    log = RunLog(out / "log.txt", quiet=quiet)
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    device = _device(cfg)
    stages = Stages(log)
    try:
        log(f"torchrefl {__version__}: capture {cfg.capture.kind}, model {cfg.fit.model}, brdf {cfg.reflectance.brdf}, "
            f"{cfg.dtype} on {device}; outputs in {out}")
        cap = load_capture(cfg, out, stages, log)
        res = fit_capture(cfg, cap["surface"], cap["obs"], stages, log, device)
        metrics = write_outputs(cfg, out, cap, res, stages, log)
        log(summary_table(metrics))
        return metrics
    finally:
        log.close()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m torchrefl.train",
        description="Estimate Pd, Ps, sigma maps from a capture described by CONFIG.",
        epilog="Options (set in the YAML file or as dotted.key=value overrides):\n" + "\n".join(describe()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("config", help="YAML config file (e.g. configs/default.yaml)")
    parser.add_argument("overrides", nargs="*", help="dotted.key=value overrides, e.g. output.dir=/tmp/x fit.holdout=[5,11]")
    parser.add_argument("--quiet", action="store_true", help="no log lines on stderr (log.txt is still written)")
    args = parser.parse_intermixed_args(argv)
    try:
        cfg = load_config(args.config, args.overrides)
        metrics = run(cfg, quiet=args.quiet)
    except TorchReflError as exc:
        print(f"torchrefl: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("torchrefl: interrupted", file=sys.stderr)
        return 130
    if args.quiet:
        print(summary_table(metrics))
    return 0


if __name__ == "__main__":
    sys.exit(main())

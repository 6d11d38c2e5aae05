"""The speed-versus-accuracy trade of the interreflection levels, measured.

For each scene (glossy Object E, configs/object_e_setup2.yaml, and the concave vase, configs/concave.yaml)
the capture is rendered once (path-traced interreflection, noise, 8 bit) with two lights held out, then
fitted at many settings, one knob at a time around a base point:

    local                          the baseline (Method I)
    radiosity  patch size          radiosity.patch_size in 1, 2, 4
               hemisphere samples  radiosity.hemisphere_samples in 64, 256, 1024
    photon     photons per light   photon.photons_per_light in 100k, 400k, 1.6M
               outer iterations    photon.outer_iterations in 1, 2, 3
               precision           dtype float32, float64
               diffuse paths       photon.diffuse_paths photons, radiosity (one of them is the scene's own)
               specular gather     photon.specular_gather 0, 64 with the radiosity paths (the other points keep
                                   the scene's own: 64 on Object E, 0 on the vase)

For every point: the wall time of the fit (precompute + initialise + fit stages), the ground-truth
errors (pd_rmse, ps_median_rel_err, sigma_median_rel_err) and the held-out image error
(holdout.mean_abs_diff_8bit). Writes tradeoff.json, a markdown table (tradeoff.md, with the machine)
and a plot of held-out error and pd_rmse against time with the Pareto front marked (tradeoff.png).

    python scripts/bench_tradeoff.py [--out outputs/tradeoff] [--full] [--scenes object_e_setup2 concave]

Default size 256 x 225 texels (1.4 deg, 1.12 mm) so the sweep takes minutes; --full uses the seed's 512 x 450;
--tiny (the test's mode) the tiny fold of scripts/tiny_mode.py at two points (local, the photon base).
Times are only comparable within one run (shared, noisy machines).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

import numpy as np

import torchrefl

sys.path.insert(0, str(Path(__file__).parent))
from tiny_mode import ROOT, TINY  # noqa: E402

QUICK = [
    "synthetic.columns=256",
    "synthetic.rows=225",
    "synthetic.angle_step_deg=1.4",
    "synthetic.height_step_mm=1.12",
    "synthetic.indirect_samples=64",
    "synthetic.supersample=2",
    "photon.smoothing=1",
]
COMMON = ["output.progress=false", "output.map_lights=0", "selection.num_lights=14", "fit.holdout=[3,10]"]
PHOTON_BASE = ["fit.model=photon", "photon.photons_per_light=400000", "photon.outer_iterations=2"]
RADIOSITY_BASE = ["fit.model=radiosity", "radiosity.patch_size=2", "radiosity.hemisphere_samples=256"]
POINTS = [
    ("local", "-", ["fit.model=local"]),
    ("radiosity", "patch_size=1", RADIOSITY_BASE + ["radiosity.patch_size=1"]),
    ("radiosity", "patch_size=2 (base)", RADIOSITY_BASE),
    ("radiosity", "patch_size=4", RADIOSITY_BASE + ["radiosity.patch_size=4"]),
    ("radiosity", "hemisphere_samples=64", RADIOSITY_BASE + ["radiosity.hemisphere_samples=64"]),
    ("radiosity", "hemisphere_samples=1024", RADIOSITY_BASE + ["radiosity.hemisphere_samples=1024"]),
    ("photon", "photons=100k", PHOTON_BASE + ["photon.photons_per_light=100000"]),
    ("photon", "photons=400k (base)", PHOTON_BASE),
    ("photon", "photons=1.6M", PHOTON_BASE + ["photon.photons_per_light=1600000"]),
    ("photon", "outer=1", PHOTON_BASE + ["photon.outer_iterations=1"]),
    ("photon", "outer=3", PHOTON_BASE + ["photon.outer_iterations=3"]),
    ("photon", "float64", PHOTON_BASE + ["dtype=float64"]),
    ("photon", "diffuse_paths=photons", PHOTON_BASE + ["photon.diffuse_paths=photons", "photon.specular_gather=0"]),
    ("photon", "diffuse_paths=radiosity", PHOTON_BASE + ["photon.diffuse_paths=radiosity", "photon.specular_gather=0"]),
    ("photon", "specular_gather=64", PHOTON_BASE + ["photon.diffuse_paths=radiosity", "photon.specular_gather=64"]),
]


def pareto(times, errors) -> np.ndarray:
    """Mask of the points no other point beats in both time and error."""
    t, e = np.asarray(times, float), np.asarray(errors, float)
    return np.array([not np.any((t <= t[i]) & (e <= e[i]) & ((t < t[i]) | (e < e[i]))) for i in range(len(t))])


def plot_tradeoff(rows: list[dict], scenes: list[str], path: Path) -> None:
    """Held-out error and pd_rmse against fit time, one column per scene, each level in its own marker, the
    Pareto front dashed and its points numbered, their settings in a key (every point is in tradeoff.md's
    table)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    marks = {"local": ("s", "tab:blue"), "radiosity": ("o", "tab:orange"), "photon": ("^", "tab:green")}
    fig = Figure(figsize=(10, 8), layout="constrained")
    axes = fig.subplots(2, len(scenes), squeeze=False)
    for j, scene in enumerate(scenes):
        sr = [r for r in rows if r["scene"] == scene]
        times = np.array([r["time_s"] for r in sr], dtype=float)
        for i, (key, label) in enumerate(
            (("holdout_mean_abs_diff_8bit", "held-out mean |difference| [DN of 255]"), ("pd_rmse", "pd_rmse"))
        ):
            err = np.array([np.inf if r[key] is None else r[key] for r in sr], dtype=float)
            front = pareto(times, err)
            ax = axes[i][j]
            for level, (marker, colour) in marks.items():
                k = [n for n, r in enumerate(sr) if r["level"] == level]
                ax.scatter(times[k], err[k], marker=marker, color=colour, s=36, zorder=3)
            order = [k for k in np.argsort(times) if front[k]]
            ax.plot(times[order], err[order], "k--", lw=1, zorder=2)
            key_lines = []
            for n, k in enumerate(order, start=1):  # numbers at the points, their settings in a key
                ax.annotate(str(n), (times[k], err[k]), xytext=(4, 4), textcoords="offset points", fontsize=9)
                key_lines.append(f"{n}: {sr[k]['level']} {sr[k]['setting']}".replace(" -", ""))
            key = [Line2D([], [], ls="none", label=line) for line in key_lines]
            ax.legend(handles=key, loc="best", handlelength=0, handletextpad=0, fontsize=8, framealpha=0.9)
            ax.set_xscale("log")
            ax.set_xlabel("fit time [s] (log)", fontsize=10)
            ax.set_ylabel(label, fontsize=10)
            ax.set_title(scene, fontsize=11)
            ax.grid(alpha=0.3, which="both")
    handles = [Line2D([], [], marker=m, color=c, ls="none", label=level) for level, (m, c) in marks.items()]
    handles.append(Line2D([], [], color="k", ls="--", lw=1, label="Pareto front (numbered: its settings in the key)"))
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=10, frameon=False)
    fig.savefig(path, dpi=100)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="outputs/tradeoff")
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--tiny", action="store_true", help="the tiny fold at two points: seconds")
    ap.add_argument("--scenes", nargs="+", default=["object_e_setup2", "concave"])
    args = ap.parse_args(argv)
    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    size = [] if args.full else QUICK
    points = POINTS
    if args.tiny:  # TINY after the bases: its photon and radiosity sizes win
        args.scenes, size = ["fold"], []
        points = [(level, knob, over + TINY) for level, knob, over in POINTS if knob in ("-", "photons=400k (base)")]
    rows = []
    for scene in args.scenes:
        config = ROOT / "configs" / f"{scene}.yaml"
        capture = out / scene / "capture_run"
        first = torchrefl.load_config(
            config, size + COMMON + (TINY if args.tiny else []) + [f"output.dir={capture}", "fit.model=local"]
        )
        print(f"{scene}: rendering the capture ...", flush=True)
        torchrefl.fit(first, overwrite=True)
        for level, knob, over in points:
            name = f"{level}_{knob.split(' ')[0].replace('=', '')}"
            cfg = torchrefl.load_config(
                config,
                size
                + COMMON
                + over
                + [
                    f"output.dir={out / scene / name}",
                    "capture.kind=cylindrical_scan",
                    f"capture.path={capture / 'capture'}",
                ],
            )
            print(f"{scene}: {level} {knob} ...", flush=True)
            m = torchrefl.fit(cfg, overwrite=True).metrics
            t = m["timing_s"]
            gt, ho = m.get("ground_truth", {}), m.get("holdout", {})
            rows.append(
                {
                    "scene": scene,
                    "level": level,
                    "setting": knob,
                    "model": m["model"],
                    "time_s": round(sum(t.get(k, 0.0) for k in ("precompute", "initialise", "fit")), 2),
                    "pd_rmse": gt.get("pd_rmse"),
                    "ps_median_rel_err": gt.get("ps_median_rel_err"),
                    "sigma_median_rel_err": gt.get("sigma_median_rel_err"),
                    "holdout_mean_abs_diff_8bit": ho.get("mean_abs_diff_8bit"),
                    "holdout_var_diff_8bit": ho.get("var_diff_8bit"),
                }
            )
            (out / "tradeoff.json").write_text(json.dumps(rows, indent=2))
    import torch

    machine = (
        f"{platform.machine()}, {platform.processor() or 'cpu'}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} threads"
    )
    lines = [
        f"Machine: {machine}; size {'tiny' if args.tiny else '512 x 450' if args.full else '256 x 225'} texels; "
        "times are precompute + "
        "initialise + fit.",
        "",
        "| scene | level | setting | time s | pd_rmse | Ps med rel | sigma med rel | held-out mean 8-bit | held-out "
        "var | Pareto |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for scene in args.scenes:
        sr = [r for r in rows if r["scene"] == scene]
        errors = [r["holdout_mean_abs_diff_8bit"] for r in sr]
        front = pareto([r["time_s"] for r in sr], [np.inf if e is None else e for e in errors])
        for r, f in zip(sr, front):
            r["pareto_holdout"] = bool(f)
        for r in sr:
            f = lambda v: f"{v:.4g}" if isinstance(v, float) else "-"
            lines.append(
                f"| {scene} | {r['level']} | {r['setting']} | {r['time_s']:.1f} | {f(r['pd_rmse'])} | "
                f"{f(r['ps_median_rel_err'])} | {f(r['sigma_median_rel_err'])} | {f(r['holdout_mean_abs_diff_8bit'])} "
                f"| {f(r['holdout_var_diff_8bit'])} | {'yes' if r.get('pareto_holdout') else ''} |"
            )
    plot_tradeoff(rows, args.scenes, out / "tradeoff.png")
    (out / "tradeoff.md").write_text("\n".join(lines) + "\n")
    (out / "tradeoff.json").write_text(json.dumps(rows, indent=2))
    print("\n".join(lines))
    print(f"\nwritten {out / 'tradeoff.md'}, {out / 'tradeoff.png'}, {out / 'tradeoff.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

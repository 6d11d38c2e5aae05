"""The summary table printed at the end of a run (and by RunResult.summary)."""

from __future__ import annotations


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
    for warning in (metrics.get("capture") or {}).get("warnings") or []:
        lines.append(f"  WARNING: {warning}")
    return "\n".join(lines)

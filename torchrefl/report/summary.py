"""The summary table printed at the end of a run (and by RunResult.summary)."""

from __future__ import annotations


def _share(value) -> str:
    return f"{value:.1%}" if isinstance(value, (int, float)) else "n/a"


def _coverage_lines(coverage: dict, source: dict) -> list[str]:
    """Where Ps and sigma come from (the share measured rather than interpolated or shared, and the largest patch
    without a highlight of its own) and the texels left unfitted for their geometry."""
    lines = []
    if isinstance(source.get("estimated"), int):
        share = {k: _share(source.get(f"{k}_share")) for k in ("measured", "interpolated", "shared", "material")}
        lines.append(
            f"  Ps/sigma measured at {share['measured']} of {source['estimated']} estimated texels "
            f"(interpolated {share['interpolated']}, shared lobe {share['shared']}, material's lobe from "
            f"interreflection {share['material']})"
        )
    patches = source.get("unmeasured_patches") or []
    if patches and isinstance(patches[0].get("texels"), int):
        p = patches[0]
        lines.append(
            f"  largest area without a highlight of its own: {p['texels']} texels, rows {p['rows'][0]}-{p['rows'][1]}, "
            f"columns {p['columns'][0]}-{p['columns'][1]} (a light giving it highlights would measure its Ps, sigma)"
        )
    if isinstance(coverage.get("untrusted_geometry"), int) and coverage["untrusted_geometry"]:
        lines.append(
            f"  untrusted geometry: {coverage['untrusted_geometry']} texels not fitted "
            "(edges, creases, mixed footprints, strips no range-fitting window describes)"
        )
    return lines


def summary_table(metrics: dict) -> str:
    rows = [("stage", "seconds")] + [(k, f"{v:.2f}") for k, v in metrics["timing_s"].items()]
    lines = ["", "== torchrefl summary =="]
    w = max(len(r[0]) for r in rows)
    lines += [f"  {a:<{w}}  {b:>8}" for a, b in rows]
    fmt = lambda d: ", ".join(f"{k} {v:.4g}" for k, v in d.items() if isinstance(v, float))
    lines.append(
        f"  texels {metrics['texels']}, lights {metrics['lights']}, model {metrics['model']}, brdf {metrics['brdf']}"
    )
    if isinstance(metrics.get("peak_memory_mb"), (int, float)):
        lines.append(f"  peak resident memory {metrics['peak_memory_mb']:.0f} MiB")
    section = lambda key: metrics[key] if isinstance(metrics.get(key), dict) else {}
    d = section("diffuse")
    if d.get("model", "lambert") != "lambert" and isinstance(d.get("k"), (int, float)):
        lines.append(
            f"  diffuse: {d['model']} k {d['k']:.4f} ({'fitted' if d.get('fitted') else 'reflectance.minnaert_k'})"
        )
    lines.append(f"  re-render (fitted): {fmt(metrics['rerender'])}")
    if section("holdout"):
        lines.append(f"  held-out lights:    {fmt(metrics['holdout'])}")
        left = metrics["holdout"].get("unestimated_observations")
        if isinstance(left, int) and left:
            lines.append(f"    ({left} held-out observations of texels without an estimate not evaluated)")
    if section("ground_truth"):
        lines.append(f"  ground truth:       {fmt(metrics['ground_truth'])}")
    lines += _coverage_lines(section("coverage"), section("specular_source"))
    s = section("selection")
    if all(isinstance(s.get(k), (int, float)) for k in ("lights_selected", "diffuse_coverage", "specular_coverage")):
        lines.append(
            f"  selection: {s['lights_selected']} lights, diffuse {s['diffuse_coverage']:.1%}, specular "
            f"{s['specular_coverage']:.1%}"
        )
    for warning in section("capture").get("warnings") or []:
        lines.append(f"  WARNING: {warning}")
    return "\n".join(lines)

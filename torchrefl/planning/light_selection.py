"""Automatic light-position selection (dissertation Ch.2).

For every candidate light p and texel x:
- measurable (eq. 2.17 plus cast shadows): V.N > 0, L.N > 0 and the segment to the light is
  unblocked (Embree occlusion rays);
- diffuse only (eq. 2.20): measurable and theta > theta_th1 (60 deg);
- strong specular (eq. 2.21): measurable and theta <= theta_th2 (20 deg);
with theta the half-angle of eq. 2.15. With lights near the camera the half-angle rarely exceeds
60 deg (it needs l and v more than 120 deg apart), so diffuse-only coverage is low under the
dissertation's literal definition (the conference papers' view-to-mirror angle gave the seed its
near-100 % diffuse coverage).
A texel is covered diffusely once it has one diffuse-only observation and specularly once it
has two strong-specular observations (eq. 3.5 needs two). A candidate's Measurability counts, per
texel, the observations of each class it gives: 0 or 1 on the scan (one camera), up to the number
of cameras on mesh_views (planning.views_selection: one observation per camera that sees the texel).
Greedy selection: each round adds the candidate that covers the most still-uncovered texels
diffusely (while diffuse coverage is below what all candidates reach) and the one that adds the
most strong-specular observations to texels that still need them (at most the two each needs; the
seed's max D_p / max S_q). Selection stops when diffuse coverage equals the all-candidates value
and specular coverage reaches th1 (stop_ratio, 80 %) of the all-candidates value, or at
max_lights; num_lights forces a count. Coverage is over the texels some camera sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from torchrefl.errors import ConfigError


@dataclass
class SelectionResult:
    """chosen: candidate indices in selection order; roles: 'diffuse' or 'specular' per pick;
    diffuse_curve / specular_curve: coverage (fraction of seen texels) after each pick;
    all_diffuse / all_specular: coverage with every candidate."""

    chosen: list
    roles: list
    diffuse_curve: list
    specular_curve: list
    all_diffuse: float
    all_specular: float
    num_candidates: int
    seen_texels: int
    positions: np.ndarray = field(default=None)

    @property
    def num_diffuse_picks(self) -> int:
        return sum(r == "diffuse" for r in self.roles)

    def table(self) -> dict:
        """A Table 2.2 analogue."""
        return {
            "lights_selected": len(self.chosen),
            "lights_for_diffuse": self.num_diffuse_picks,
            "diffuse_coverage": self.diffuse_curve[-1] if self.diffuse_curve else 0.0,
            "specular_coverage": self.specular_curve[-1] if self.specular_curve else 0.0,
            "diffuse_coverage_all_candidates": self.all_diffuse,
            "specular_coverage_all_candidates": self.all_specular,
            "candidates": self.num_candidates,
        }

    def to_json(self) -> dict:
        out = self.table()
        out.update(
            {
                "chosen": [int(c) for c in self.chosen],
                "roles": list(self.roles),
                "diffuse_curve": [float(x) for x in self.diffuse_curve],
                "specular_curve": [float(x) for x in self.specular_curve],
                "positions_mm": None if self.positions is None else np.asarray(self.positions)[self.chosen].tolist(),
            }
        )
        return out


def measurability(
    theta_h: np.ndarray, measurable: np.ndarray, theta_diffuse_deg: float = 60.0, theta_specular_deg: float = 20.0
) -> tuple[np.ndarray, np.ndarray]:
    """(P, T) bool diffuse-only (eq. 2.20) and strong-specular (eq. 2.21) masks."""
    diffuse = measurable & (theta_h > math.radians(theta_diffuse_deg))
    specular = measurable & (theta_h <= math.radians(theta_specular_deg))
    return diffuse, specular


@dataclass(frozen=True)
class Measurability:
    """What each of P candidate lights gives T texels: diffuse, specular (P, T) the number of diffuse-only
    (eq. 2.20) and strong-specular (eq. 2.21) observations (bool masks count 0 / 1); seen (T,) bool, the texels
    some camera sees (coverage is a fraction of these)."""

    diffuse: np.ndarray
    specular: np.ndarray
    seen: np.ndarray


def greedy_select(
    measured: Measurability,
    stop_ratio: float = 0.8,
    max_lights: int = 20,
    num_lights: int | None = None,
) -> SelectionResult:
    """Greedy max-D / max-S selection over the candidates' observation counts, restricted to the seen texels."""
    seen = np.asarray(measured.seen, dtype=bool)
    P = measured.diffuse.shape[0]
    if num_lights is not None and not (1 <= num_lights <= P):
        raise ConfigError(f"selection.num_lights = {num_lights} must be between 1 and the {P} candidates")
    Dm = np.asarray(measured.diffuse)[:, seen].astype(np.float32)
    Sm = np.asarray(measured.specular)[:, seen].astype(np.float32)
    n = max(int(seen.sum()), 1)
    all_d = float((Dm.sum(0) >= 1).sum()) / n
    all_s = float((Sm.sum(0) >= 2).sum()) / n
    d_count = np.zeros(Dm.shape[1], dtype=np.float32)
    s_count = np.zeros(Dm.shape[1], dtype=np.float32)
    chosen, roles, dcurve, scurve = [], [], [], []
    available = np.ones(P, dtype=bool)
    target = num_lights if num_lights is not None else max_lights

    def cov():
        return float((d_count >= 1).sum()) / n, float((s_count >= 2).sum()) / n

    def take(p: int, role: str) -> None:
        available[p] = False
        chosen.append(p)
        roles.append(role)
        d_count[:] += Dm[p]
        s_count[:] += Sm[p]
        dc, sc = cov()
        dcurve.append(dc)
        scurve.append(sc)

    def pick(role: str) -> bool:
        # observations that count: up to what each texel still needs (1 diffuse-only, 2 strong-specular)
        need = np.maximum(1.0 - d_count, 0.0) if role == "diffuse" else np.maximum(2.0 - s_count, 0.0)
        gain = np.minimum(Dm if role == "diffuse" else Sm, need[None]).sum(1)
        gain = np.where(available, gain, -1.0)
        p = int(np.argmax(gain))
        if gain[p] <= 0:
            return False
        take(p, role)
        return True

    while len(chosen) < target and available.any():
        dc, sc = cov()
        diffuse_done = dc >= all_d - 1e-12
        spec_done = sc >= stop_ratio * all_s - 1e-12
        if num_lights is None and diffuse_done and spec_done:
            break
        progressed = False
        if not diffuse_done:
            progressed |= pick("diffuse")
        if len(chosen) < target and (not spec_done or num_lights is not None):
            progressed |= pick("specular")
        if not progressed:
            if num_lights is None:
                break
            # forced count and no candidate adds coverage: take the one with most observations
            score = np.where(available, Sm.sum(1) + Dm.sum(1), -1.0)
            take(int(np.argmax(score)), "specular")
    return SelectionResult(chosen, roles, dcurve, scurve, all_d, all_s, P, int(seen.sum()))


def coverage_figure(result: SelectionResult):
    """A Fig. 2.12 analogue: diffuse and specular coverage against the number of selected lights, each pick marked
    by its role, as a matplotlib Figure (not pyplot's: drawing it changes no global matplotlib state)."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D

    k = np.arange(1, len(result.chosen) + 1)
    roles = np.array(result.roles, dtype=object)
    marks = {"diffuse": ("o", "tab:blue"), "specular": ("^", "tab:orange")}
    fig = Figure(figsize=(10, 4.2), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    for ax, curve, full, title in (
        (axes[0], result.diffuse_curve, result.all_diffuse, "diffuse only (1 observation per texel)"),
        (axes[1], result.specular_curve, result.all_specular, "strong specular (2 observations per texel)"),
    ):
        y = np.array(curve, dtype=np.float64) * 100
        ax.plot(k, y, "-", color="0.5", lw=1.2)
        for role, (marker, colour) in marks.items():
            picked = roles == role
            ax.plot(k[picked], y[picked], marker, color=colour, ms=7, ls="none")
        ax.axhline(full * 100, color="0.3", ls="--", lw=1.2)
        ax.set_xlabel("number of selected lights", fontsize=10)
        ax.set_title(title, fontsize=11)
        ax.set_ylim(0, 105)
        ax.set_xticks(k if len(k) <= 20 else ax.get_xticks())
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("coverage of the seen texels [%]", fontsize=10)
    handles = [
        Line2D(
            [], [], marker=marks["diffuse"][0], color=marks["diffuse"][1], ls="none", label="light picked for diffuse"
        ),
        Line2D(
            [],
            [],
            marker=marks["specular"][0],
            color=marks["specular"][1],
            ls="none",
            label="light picked for specular",
        ),
        Line2D([], [], color="0.3", ls="--", label=f"all {result.num_candidates} candidate lights"),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=3, fontsize=10, frameon=False)
    fig.suptitle(f"light selection: {len(result.chosen)} of {result.num_candidates} candidates", fontsize=12)
    return fig


def plot_coverage(result: SelectionResult, path) -> None:
    """Save coverage_figure(result) as a PNG at `path` (100 dpi: 1000 pixels wide)."""
    coverage_figure(result).savefig(path, dpi=100)


def select_for_scan(
    geom, candidates: np.ndarray, selection_cfg, reflectance_cfg, shadow_offset: float
) -> SelectionResult:
    """Light selection for a cylindrical scan: candidate head-frame positions (P, 3) against the
    scan's Surface, with cast shadows from Embree (torchrefl.capture.cylindrical_scan.observation_geometry)."""
    import torch

    from torchrefl.capture.cylindrical_scan import observation_geometry
    from torchrefl.core.brdf import half_angle

    og = observation_geometry(geom, candidates, shadow_offset=shadow_offset)
    n = geom.surface.normals.float()[None]
    th = half_angle(n, torch.from_numpy(og["light_dir"]), torch.from_numpy(og["view_dir"])[None]).numpy()
    measurable = og["seen"][None] & (og["cos_l"] > 0) & ~og["shadowed"]
    dmask, smask = measurability(th, measurable, reflectance_cfg.theta_diffuse_deg, reflectance_cfg.theta_specular_deg)
    sel = greedy_select(
        Measurability(dmask, smask, og["seen"]),
        selection_cfg.stop_ratio,
        selection_cfg.max_lights,
        selection_cfg.num_lights,
    )
    sel.positions = np.asarray(candidates)
    return sel

"""The adaptive capture loop of a dry run (`python -m torchrefl.rig capture --dry-run --adaptive`): capture a start set
of lights, fit, choose the next lights from the fit, capture them, refit, until the stopping rule or the light budget.

- Start set: the first `start` lights of the coverage-greedy selection (torchrefl.planning.light_selection) of the
  scene's config on its light grid.
- Each round fits the whole folder (every image so far) with the scene's config read as a cylindrical_scan capture
  (plus the user's `fit_set` overrides) into OUT/adaptive/round_NN, from the previous round's parameters
  (fit.init_from: torchrefl.fit.warm_start).
- Next lights: a chooser (run folder, candidate positions (M, 3) head frame mm not yet captured, k) -> indices into
  the candidates in choice order; the default is the next-best-light planner (torchrefl.planning.next_best),
  `CoverageOrder` continues the coverage-greedy order instead.
- Stopping rule: the share of the estimated texels whose Ps (every channel) and sigma have std / value at most 0.1
  (metrics.json `uncertainty.determined_share`, torchrefl.report.uncertainty) reaches `target` (0.9) of the share the
  light grid can reach (`reachable`: the next-best planner's predicted share of texels with Ps and sigma known to 0.1
  were every grid light not yet captured added to this round's fit, planning.next_best.Planner.reachable, recomputed
  each round); else the budget `max_lights`, or no candidate left. Both sides count the same thing, Ps and sigma
  known to 10 % by the same Fisher-information model (the fit's uncertainty), the ceiling at the round's estimate
  with all the grid's images; no truth needed, so it works on a real object. The share is taken relative to the
  ceiling because texels that the grid cannot determine never are: an absolute share (say 90 %) is out of reach on
  the default object and would always end by the budget, and a share that suits one object is lax or out of reach
  on another. Where the fit already reaches the ceiling (or more) the statistic is 1.
- The rounds are logged in OUT/adaptive.json (rewritten whole after each round: AdaptiveReport) and one progress
  line per round.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from torchrefl.core.atomic_files import atomic_write_text
from torchrefl.errors import RigError
from torchrefl.rig.plan import target_key

#: (run folder, candidate head-frame positions (M, 3) mm, k) -> up to k indices into the candidates, in choice order
Chooser = Callable[[Path, np.ndarray, int], list[int]]
#: (run folder, candidate head-frame positions (M, 3) mm not yet captured) -> the predicted determined share were all
#: of them captured (module docstring)
Ceiling = Callable[[Path, np.ndarray], float]
#: the report file and the folder of the rounds' fits, inside the capture folder
REPORT = "adaptive.json"
ROUNDS = "adaptive"


class NextBestRounds:
    """The next-best-light planner (torchrefl.planning.next_best.Planner) as the loop's chooser and ceiling: both ask
    about the same round's run and candidates, so the planner's inputs (every candidate's information, the costly
    part) are computed once per round."""

    def __init__(self):
        self._key, self._planner = None, None

    def planner(self, run_dir: Path, candidates: np.ndarray):
        key = (str(Path(run_dir).resolve()), np.asarray(candidates, dtype=np.float64).tobytes())
        if key != self._key:
            try:
                from torchrefl.planning.next_best import Planner
                from torchrefl.planning.run_scene import load_run_scene
            except ImportError:
                raise RigError(
                    "adaptive capture: the next-best-light planner (torchrefl.planning.next_best) is not in this "
                    "install; it predicts the stopping rule's reachable share"
                ) from None
            self._key, self._planner = key, Planner(load_run_scene(Path(run_dir)), candidates)
        return self._planner

    def choose(self, run_dir: Path, candidates: np.ndarray, k: int) -> list[int]:
        """The planner's greedy choice of k (a Chooser)."""
        return [int(i) for i in self.planner(run_dir, candidates).choose(k).chosen]

    def reachable(self, run_dir: Path, candidates: np.ndarray) -> float:
        """The planner's predicted determined share with every candidate added (a Ceiling)."""
        return self.planner(run_dir, candidates).reachable()


class CoverageOrder:
    """A chooser that takes the candidates in a fixed order (e.g. the coverage-greedy selection's) and ignores the
    fit: order (N, 3) head-frame positions mm, best first; candidates not in it come last, in their given order."""

    def __init__(self, order: np.ndarray):
        self.rank = {target_key(p): k for k, p in enumerate(np.asarray(order, dtype=np.float64))}

    def __call__(self, run_dir: Path, candidates: np.ndarray, k: int) -> list[int]:
        ranks = [self.rank.get(target_key(p), len(self.rank) + i) for i, p in enumerate(candidates)]
        return [int(i) for i in np.argsort(ranks, kind="stable")[:k]]


@dataclass(frozen=True)
class AdaptiveSettings:
    """start: lights of the first round; per_round: lights added per round; max_lights: the light budget;
    target: the stopping rule's fraction of the reachable share (module docstring); fit_set: dotted overrides of
    every round's fit config (e.g. fit.iterations=30)."""

    start: int = 6
    per_round: int = 2
    max_lights: int = 20
    target: float = 0.9
    fit_set: tuple[str, ...] = ()

    def check(self, candidates: int) -> None:
        """A RigError naming the option at fault (the start set, the budget, the rule's share)."""
        if self.start < 1 or self.per_round < 1:
            raise RigError(f"--start {self.start} and --per-round {self.per_round}: expected at least 1 light each")
        if self.max_lights < self.start:
            raise RigError(
                f"--max-lights {self.max_lights} is below --start {self.start}: the budget must hold the start set"
            )
        if self.start > candidates:
            raise RigError(f"--start {self.start}: the light grid has only {candidates} positions")
        if not 0.0 < self.target <= 1.0:
            raise RigError(f"--target {self.target}: expected a fraction in (0, 1]")


@dataclass(frozen=True)
class Ranking:
    """The candidates ranked by the coverage-greedy selection: order (N, 3) head-frame positions mm, best first (the
    start set takes the first)."""

    order: np.ndarray


@dataclass
class Round:
    """One round: its number (1 = the start set), the lights captured so far, the head-frame positions added this
    round (mm), its fit's determined_share, the reachable share (the planner's ceiling, module docstring) and the
    stopping statistic determined_share / reachable (None: the fit wrote no uncertainty, or no candidate is left),
    the times (s) the chooser took to pick the added lights (0 for the start set), their capture and the fit, the
    fit's run folder (relative to the capture folder), its errors against the truth where the scene has one
    (metrics.json ground_truth: pd_rmse, ps_median_rel_err, sigma_median_rel_err) and the time (s) the reachable
    share took (with the next-best planner it computes the candidates' information, which the next choice reuses)."""

    round: int
    lights: int
    added_mm: list
    determined_share: float | None
    reachable: float | None
    statistic: float | None
    choose_s: float
    capture_s: float
    fit_s: float
    run: str
    ground_truth: dict | None = None
    reachable_s: float = 0.0


@dataclass
class AdaptiveReport:
    """OUT/adaptive.json: the settings, the rounds, why the loop stopped (rule, budget, candidates, or running while
    it runs) and the total wall time (s)."""

    settings: dict
    rounds: list[Round] = field(default_factory=list)
    stopped_by: str = "running"
    wall_s: float = 0.0

    def write(self, folder: Path) -> None:
        atomic_write_text(Path(folder) / REPORT, json.dumps(asdict(self), indent=2) + "\n")


def round_line(r: Round, target: float) -> str:
    """The progress line of a round."""
    share = "none" if r.determined_share is None else f"{r.determined_share:.3f}"
    if r.statistic is not None:
        share += f" ({r.statistic:.2f} of the reachable {r.reachable:.3f}, target {target:g})"
    added = ", ".join(f"[{p[0]:g}, {p[1]:g}]" for p in r.added_mm)
    return (
        f"adaptive round {r.round}: {r.lights} lights (+{len(r.added_mm)}: {added}); determined_share {share}; "
        f"choice {r.choose_s:.1f} s, capture {r.capture_s:.1f} s, fit {r.fit_s:.1f} s, "
        f"reachable share {r.reachable_s:.1f} s"
    )


def _ground_truth(metrics: dict) -> dict | None:
    gt = metrics.get("ground_truth")
    if not gt:
        return None
    return {k: gt.get(k) for k in ("pd_rmse", "ps_median_rel_err", "sigma_median_rel_err")}


def run_adaptive(
    out: Path,
    candidates: np.ndarray,
    ranking: Ranking,
    capture: Callable[[np.ndarray], None],
    fit: Callable[[Path, Path | None], dict],
    settings: AdaptiveSettings,
    chooser: Chooser | None = None,
    progress: Callable[[str], None] = print,
    ceiling: Ceiling | None = None,
) -> AdaptiveReport:
    """The loop (module docstring) into the capture folder `out`.

    candidates (M, 3): the head-frame light positions the rig can reach (mm); ranking: the start set's order
    (coverage_greedy_ranking); capture(positions (n, 3)): captures every
    given position into `out` (those already recorded are skipped); fit(run_dir, init_from or None) -> metrics:
    fits `out` into run_dir, warm-started from init_from; chooser and ceiling: the next lights and the stopping rule's
    reachable share (both the next-best planner's where not given, NextBestRounds). Returns the report (also written
    to out/adaptive.json)."""
    out = Path(out)
    candidates = np.asarray(candidates, dtype=np.float64)
    settings.check(len(candidates))
    planner = NextBestRounds()
    chooser = planner.choose if chooser is None else chooser
    ceiling = planner.reachable if ceiling is None else ceiling
    report = AdaptiveReport(settings=asdict(settings))
    t0 = time.perf_counter()
    taken: list[np.ndarray] = []
    added = [np.asarray(p, dtype=np.float64) for p in np.asarray(ranking.order)[: settings.start]]
    previous, choose_s = None, 0.0
    while True:
        taken += added
        t = time.perf_counter()
        capture(np.array(taken))
        capture_s = time.perf_counter() - t
        run_dir = out / ROUNDS / f"round_{len(report.rounds) + 1:02d}"
        t = time.perf_counter()
        metrics = fit(run_dir, previous)
        fit_s = time.perf_counter() - t
        share = (metrics.get("uncertainty") or {}).get("determined_share")
        done = {target_key(p) for p in taken}
        remaining = np.array([p for p in candidates if target_key(p) not in done]).reshape(-1, 3)
        reachable = statistic = None
        t = time.perf_counter()
        if share is not None and len(remaining):
            reachable = float(ceiling(run_dir, remaining))
            statistic = 1.0 if share >= reachable else share / reachable
        r = Round(
            len(report.rounds) + 1,
            len(taken),
            [[float(v) for v in p] for p in added],
            share,
            reachable,
            statistic,
            round(choose_s, 3),
            round(capture_s, 3),
            round(fit_s, 3),
            str(run_dir.relative_to(out)),
            _ground_truth(metrics),
            round(time.perf_counter() - t, 3),
        )
        report.rounds.append(r)
        report.wall_s = round(time.perf_counter() - t0, 3)
        progress(round_line(r, settings.target))
        k = min(settings.per_round, settings.max_lights - len(taken), len(remaining))
        if statistic is not None and statistic >= settings.target:
            report.stopped_by = "rule"
        elif len(taken) >= settings.max_lights:
            report.stopped_by = "budget"
        elif k <= 0:
            report.stopped_by = "candidates"
        report.write(out)
        if report.stopped_by != "running":
            progress(f"adaptive capture stopped by the {report.stopped_by} after {len(taken)} lights")
            return report
        t = time.perf_counter()
        picked = checked_choice(chooser(run_dir, remaining, k), len(remaining), k)
        choose_s = time.perf_counter() - t
        added = [remaining[i] for i in picked]
        previous = run_dir


def checked_choice(chosen, m: int, k: int) -> list[int]:
    """The chooser's indices as ints, checked: between 1 and k distinct indices into the m candidates (a RigError
    otherwise)."""
    try:
        picked = [int(i) for i in chosen]
    except (TypeError, ValueError):
        raise RigError(f"adaptive capture: the chooser returned {chosen!r}, expected a list of indices") from None
    if not 1 <= len(picked) <= k or len(set(picked)) != len(picked) or not all(0 <= i < m for i in picked):
        raise RigError(
            f"adaptive capture: the chooser returned {picked}, expected 1 to {k} distinct indices into the {m} "
            "candidates not yet captured"
        )
    return picked


def round_config(scene, scene_set, out: Path, run_dir: Path, init_from: Path | None, fit_set=()):
    """The fit config of a round: the scene's config (file or bundled name, and its --scene-set overrides) reading
    the capture folder `out` as a cylindrical_scan into run_dir, warm-started from init_from, then fit_set."""
    from torchrefl.config import load_config

    overrides = [
        *scene_set,
        "capture.kind=cylindrical_scan",
        f"capture.path={Path(out).resolve()}",
        f"output.dir={Path(run_dir).resolve()}",
        *([f"fit.init_from={Path(init_from).resolve()}"] if init_from is not None else []),
        *fit_set,
    ]
    return load_config(scene, overrides)


def coverage_greedy_ranking(cfg, folder: Path, candidates: np.ndarray) -> Ranking:
    """The Ranking of the candidates (M, 3) by the coverage-greedy selection of cfg for the scan geometry in `folder`
    (the selection forced to rank every candidate: selection.num_lights = M)."""
    import dataclasses

    from torchrefl.capture.cylindrical_scan import CylindricalScanLoader
    from torchrefl.planning.capture_plan import choose_lights

    geom = CylindricalScanLoader().load_geometry(Path(folder), cfg, check_scale=False)
    every = dataclasses.replace(cfg, selection=dataclasses.replace(cfg.selection, num_lights=len(candidates)))
    sel = choose_lights(every, geom, candidates)
    return Ranking(np.asarray(candidates)[sel.chosen])

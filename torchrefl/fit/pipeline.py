"""The fit of one capture: observe, choose and prepare a transport level, start, refine, report.

The transport level (torchrefl.transport.levels: local = Method I, radiosity = Method II, photon = Method
III, or auto's choice among them) precomputes what it needs, corrects the closed-form start and predicts
the images; this module owns what every level shares: the observation masks and classes, the closed-form
start (torchrefl.fit.initialise), the objective and the refinement loop.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import torch

from torchrefl.capture.base import Capture
from torchrefl.config import Config
from torchrefl.core.checkpoints import Checkpoints
from torchrefl.core.params import TexelParams
from torchrefl.core.progress import Stages, bar
from torchrefl.errors import ConfigError
from torchrefl.fit.emitter_fill import nearest_fitted
from torchrefl.fit.initialise import COVER_MATERIAL, COVER_MISFIT, initialise_local, mark_untrusted
from torchrefl.fit.misfit import MISFIT_DEVIATIONS, misfit_texels, near_edge
from torchrefl.fit.observe import observe
from torchrefl.fit.outer_skip import quiet_texels
from torchrefl.fit.outer_state import INITIALISE, OUTER, outer_state, restore_outer, saved_memory
from torchrefl.fit.reestimate import reestimate
from torchrefl.fit.refine import Objective, Prior, neighbour_pairs, refine
from torchrefl.fit.result import FitResult
from torchrefl.fit.texel_chunks import texel_chunks
from torchrefl.fit.texel_lm import levenberg_marquardt
from torchrefl.fit.uncertainty import fit_uncertainty
from torchrefl.fit.warm_start import warm_start
from torchrefl.transport.levels.auto import choose, named_level, prepare
from torchrefl.transport.levels.base import LevelInputs, TransportLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.memory_estimate import check_level_memory


def held_out(holdout: list, num_lights: int) -> torch.Tensor:
    """(P,) bool: the lights fit.holdout names (a ConfigError for an index the capture does not have)."""
    bad = [i for i in holdout if i >= num_lights]
    if bad:
        raise ConfigError(
            f"fit.holdout: light indices {bad} out of range (the capture has {num_lights} lights, "
            f"indices 0..{num_lights - 1})"
        )
    held = torch.zeros(num_lights, dtype=torch.bool)
    held[list(holdout)] = True
    return held


def emitter_source(cfg: Config, inputs: LevelInputs, init, log) -> torch.Tensor | None:
    """(T,) the nearest fitted texel of every texel that has no fitted observation: what those texels reflect when
    the interreflection levels light the object (black emitters lost Object E +0.2 % Pd on the lower plate)."""
    if cfg.fit.model == "local" or not inputs.surface.has_mesh:
        return None
    source = nearest_fitted(inputs.surface.positions, init.defined)
    filled = int((source != torch.arange(inputs.surface.num_texels)).sum())
    if not filled:
        return None
    log(
        f"interreflection: {filled} texels without a fitted observation reflect with the parameters of "
        "the nearest fitted texel"
    )
    return source


class ObjectiveFactory:
    """(predict, mask) -> Objective with the fit's loss, priors and smoothness; `lend` and `pool` move the lobe prior
    of texels that took measured texels' lobes or their material's lobe during the fit (torchrefl.fit.reestimate) to
    those lobes."""

    def __init__(self, cfg: Config, inputs: LevelInputs, init):
        fc, device, T = cfg.fit, inputs.device, inputs.surface.num_texels
        # a shared lobe has no per-texel values to pull towards (the pull collapsed the object's lobe to Ps ~ 0)
        prior_weight = 0.0 if fc.specular == "shared" else fc.prior_weight
        self.lobe_prior = Prior(
            (~init.known).to(device), init.ps.clone().to(device), init.sigma.clone().to(device), prior_weight
        )
        self.priors = [self.lobe_prior]
        if fc.specular == "pooled" and init.shared_lobe is not None:
            self.priors.append(
                Prior(
                    torch.ones(T, dtype=torch.bool, device=device),
                    init.shared_lobe[0].expand(T, -1).to(device),
                    init.shared_lobe[1].expand(T).to(device),
                    fc.pooling,
                )
            )
        s = inputs.surface
        self.neighbours = neighbour_pairs(s.neighbours).to(device) if fc.smoothness > 0 else None
        self.intensity = inputs.obs.intensity.to(device)
        self.fc = fc
        self.pooled: torch.Tensor | None = None  # texels whose lobe is their material's (pool)

    def lend(self, lent: torch.Tensor, params: TexelParams) -> None:
        """The lobe prior of the texels in lent (T,) bool pulls towards their current lobes."""
        prior = self.lobe_prior
        m = lent.to(prior.mask.device)
        with torch.no_grad():
            prior.ps[m] = params.ps().detach()[m].to(prior.ps)
            prior.sigma[m] = params.sigma().detach()[m].to(prior.sigma)

    def pool(self, pooled: torch.Tensor | None, params: TexelParams) -> None:
        """As lend, for the texels pooled (T,) bool that took their material's lobe at this re-estimation
        (torchrefl.fit.material_lobe; None: none); remembered in `pooled` for the coverage map."""
        self.pooled = None if pooled is None else pooled.cpu()
        if pooled is not None:
            self.lend(pooled, params)

    def state(self) -> dict:
        """What the re-estimations changed (the lobe prior's targets, the pooled texels): a checkpoint's share."""
        prior = self.lobe_prior
        return {"ps": prior.ps.detach().clone(), "sigma": prior.sigma.detach().clone(), "pooled": self.pooled}

    def restore(self, state: dict) -> None:
        """Put back what state() returned."""
        with torch.no_grad():
            self.lobe_prior.ps.copy_(state["ps"])
            self.lobe_prior.sigma.copy_(state["sigma"])
        self.pooled = state["pooled"]

    def __call__(self, predict, mask) -> Objective:
        fc = self.fc
        return Objective(
            predict=predict,
            intensity=self.intensity,
            weight=mask.to(self.intensity.device),
            loss=fc.loss,
            loss_scale_8bit=fc.loss_scale_8bit,
            priors=self.priors,
            smoothness=fc.smoothness,
            neighbours=self.neighbours,
        )


def refinement_optimizer(cfg: Config, params: TexelParams) -> str:
    """fit.optimizer, except lbfgs for lm where the objective couples texels (a shared lobe, fit.smoothness): the
    per-texel solver needs independent texels."""
    name = cfg.fit.optimizer
    return "lbfgs" if name == "lm" and (params.shared_specular or cfg.fit.smoothness > 0) else name


def refit(
    level: TransportLevel,
    params: TexelParams,
    make_objective: ObjectiveFactory,
    cfg: Config,
    checkpoints: Checkpoints | None = None,
) -> list[float]:
    """The refinement loop every level shares (transport.levels.base); returns the loss history. checkpoints: the
    state after the first refresh and after each outer iteration is saved there (torchrefl.fit.outer_state), and
    the loop continues from the one saved last."""
    fc = cfg.fit
    optimizer = refinement_optimizer(cfg, params)
    checkpoints = checkpoints or Checkpoints(Path("."), enabled=False)
    saved = checkpoints.load(OUTER)
    if saved is None:
        history, done = [], 0
        level.refresh(params, 0)
        checkpoints.save(OUTER, outer_state(0, level, params, make_objective, history))
    else:
        history, done = restore_outer(saved, level, params, make_objective)
        level.inputs.log(f"resume: {level.name} refinement after outer iteration {done} of {level.refits}")
    memory = saved_memory(saved)  # the indirect terms the last re-estimation saw
    for k in range(done, level.refits):
        before = [v.detach().clone() for v in params.values()]
        again = reestimate(level, params, cfg, memory)
        if memory is not None and again.memory is not None:
            level.inputs.log(
                f"{level.name} refit {k + 1}: the sigma search on the {again.searched} texels with specular evidence "
                f"whose indirect light moved by more than {fc.noise_floor_dn:g} DN"
            )
        memory = again.memory
        if again.restarted:
            level.inputs.log(
                f"{level.name} refit {k + 1}: {again.restarted} texels restart from the sigma search on direct plus "
                "indirect light"
            )
        if again.lent is not None:
            make_objective.lend(again.lent, params)
            level.inputs.log(
                f"{level.name} refit {k + 1}: {int(again.lent.sum())} texels without highlights take the lobes now "
                "measured on texels of their colour"
            )
        if isinstance(make_objective, ObjectiveFactory):  # a plain (predict, mask) -> Objective has no priors
            make_objective.pool(again.pooled, params)
        quiet = quiet_refit(level, params, before, k, fc.noise_floor_dn) if optimizer == "lm" else None
        for step in level.steps(k):
            train = None if step.train is None else [getattr(params, name) for name in step.train]
            objective = make_objective(level.predict, step.mask)
            with bar(step.iterations, step.label, cfg.output.progress) as pb:
                if optimizer == "lm":
                    history += levenberg_marquardt(
                        params,
                        objective,
                        level.texel_model,
                        step.iterations,
                        progress=pb,
                        train=train,
                        skip=quiet,
                        texels_model=level.texel_model,
                    )
                else:
                    history += refine(
                        params, objective, optimizer, step.iterations, fc.learning_rate, progress=pb, train=train
                    )
        stop = level.converged(params)
        if stop:  # the refresh would only score parameters that moved less than they are known
            level.inputs.log(f"{level.name}: {stop}; {k + 1} of {level.refits} outer iterations run")
            break
        level.refresh(params, k + 1)
        checkpoints.save(OUTER, outer_state(k + 1, level, params, make_objective, history, memory))
    level.finish(params)
    if not history:  # no refit (e.g. photon.outer_iterations 0): the start's loss
        with torch.no_grad():
            history = [float(make_objective(level.predict, level.inputs.fit_mask)(params))]
    return history


def quiet_refit(level: TransportLevel, params: TexelParams, before: list, k: int, floor_dn: float):
    """(T,) bool texels refit k (from 0) leaves alone, or None: from the second refit on, those whose predicted
    indirect light stays below floor_dn on all their fitted observations (torchrefl.fit.outer_skip) and that the
    re-estimation did not move from `before` (their values before it)."""
    if k == 0:
        return None
    with torch.no_grad():
        pd, ps, sigma = (v.detach() for v in params.values())
        terms = level.indirect_terms(pd)
        if terms is None:
            return None
        quiet = quiet_texels(terms, pd, ps, sigma, level.inputs.fit_mask, floor_dn)
        for old, new in zip(before, (pd, ps, sigma)):
            quiet &= (old == new).reshape(len(quiet), -1).all(1)
    if bool(quiet.any()):
        level.inputs.log(
            f"{level.name} refit {k + 1}: {int(quiet.sum())} texels with predicted interreflection below {floor_dn:g} "
            "DN keep their values"
        )
    return quiet


def level_inputs(cfg: Config, capture: Capture, log, device: torch.device = torch.device("cpu")):
    """What every level is built from (LevelInputs), and the observation summary (Observed) behind it."""
    held = held_out(cfg.fit.holdout, capture.obs.num_lights)
    seen = observe(cfg, capture.surface, capture.obs, held, log)
    chunks = texel_chunks(cfg, capture.surface.num_texels, seen.fit_mask, log)
    start = partial(
        initialise_local,
        seen.terms,
        cls=seen.classes,
        n_spec=seen.counts["T_spec"],
        fit_mask=seen.fit_mask,
        surface=capture.surface,
        chunks=chunks,
        **seen.initialise_options,
    )
    inputs = LevelInputs(
        cfg,
        capture.surface,
        capture.obs,
        seen.terms,
        seen.classes,
        seen.fit_mask,
        seen.eval_mask,
        device,
        log,
        start,
        chunks,
    )
    return inputs, seen


def start_params(cfg: Config, init, dtype: torch.dtype, device: torch.device) -> TexelParams:
    """The texel tensors at the start, within the reflectance bounds (one lobe with fit.specular: shared)."""
    rc = cfg.reflectance
    shared = cfg.fit.specular == "shared"
    pd, ps, sigma = (x.to(dtype) for x in (init.pd, init.ps, init.sigma))
    return TexelParams(pd, ps, sigma, rc.sigma_min, rc.sigma_max, shared_specular=shared, ps_max=rc.ps_max).to(device)


def fit_result(pd, ps, sigma, predicted, history, seen, init, level: TransportLevel, optimizer: str) -> FitResult:
    """The FitResult of a finished fit: the estimate, what the fit saw (seen), the start (init) and the level."""
    init_counts = {
        "pd_closed_form": int(init.pd_from_diffuse.sum()),
        "spec_closed_form": int(init.spec_closed_form.sum()),
        "spec_known": int(init.known.sum()),
    }
    return FitResult(
        pd=pd.cpu(),
        ps=ps.cpu(),
        sigma=sigma.cpu(),
        predicted=predicted,
        fit_mask=seen.fit_mask,
        eval_mask=seen.eval_mask & init.defined[None],
        counts=seen.counts,
        coverage=init.coverage,
        estimated=init.defined,
        init_counts=init_counts,
        history=history,
        optimizer=optimizer,
        level=level.name,
        model_reason=level.reason,
        diffuse=seen.diffuse,
        model_numbers=level.model_numbers,
        photon=level.report(),
        holdout_unestimated=int((seen.eval_mask & ~init.defined[None]).sum()),
    )


def drop_misfits(result: FitResult, capture: Capture, log) -> None:
    """Texels next to an edge or untrusted geometry that the fitted model cannot explain (torchrefl.fit.misfit)
    lose their estimate: coverage code 6, out of the masks every metric uses."""
    s = capture.surface
    trusted = torch.ones(s.num_texels, dtype=torch.bool) if capture.untrusted is None else ~capture.untrusted.bool()
    edge = near_edge(s.neighbours, trusted)
    bad = misfit_texels(result.predicted, capture.obs.intensity, result.fit_mask, result.estimated) & edge
    result.misfit = int(bad.sum())
    if not result.misfit:
        return
    result.estimated = result.estimated & ~bad
    result.fit_mask = result.fit_mask & ~bad[None]
    result.eval_mask = result.eval_mask & ~bad[None]
    result.coverage = torch.where(bad, torch.full_like(result.coverage, COVER_MISFIT), result.coverage)
    log(
        f"{result.misfit} texels the fitted model cannot explain (RMS residual over {MISFIT_DEVIATIONS:g} robust "
        "deviations above the median texel's, next to an edge or untrusted geometry: mixed footprints the range "
        "data missed) have no estimate"
    )


def fit_capture(
    cfg: Config, capture: Capture, stages: Stages, log, device: torch.device, checkpoints: Checkpoints | None = None
) -> FitResult:
    """Classify, start, and refine at the transport level cfg.fit.model (or auto's choice). checkpoints: the start
    and the refinement's outer iterations are saved there, and a resumed run continues from them."""
    checkpoints = checkpoints or Checkpoints(Path("."), enabled=False)
    with stages.stage("precompute"):
        inputs, seen = level_inputs(cfg, capture, log, device)
        level = named_level(inputs)
        prepare(level)
    with stages.stage("initialise"):
        saved = checkpoints.load(INITIALISE)
        first = inputs.initialise(capture.obs.intensity) if saved is None else saved["first"]
        source = emitter_source(cfg, inputs, first, log)
        if source is not None:
            level.use_emitters(source)
        if cfg.fit.model == "auto" and isinstance(level, RadiosityLevel):
            level = choose(level, first)
            if level.name == "photon":
                check_level_memory(level)
                level.prepare()
        if saved is None:
            init = level.start(first)
            if cfg.fit.init_from:
                init = warm_start(cfg, capture.surface, init, log)
            checkpoints.save(INITIALISE, {"first": first, "init": init})
        else:
            init = saved["init"]
            log(f"resume: the {level.name} level's start from the checkpoint")
    log(init.note)
    log(f"transport level: {level.name} ({level.reason})")
    with stages.stage("fit"):
        params = start_params(cfg, init, capture.obs.intensity.dtype, device)
        optimizer = refinement_optimizer(cfg, params)
        if optimizer != cfg.fit.optimizer:
            why = "one lobe for the whole object (fit.specular: shared)" if params.shared_specular else "fit.smoothness"
            log(f"fit.optimizer {cfg.fit.optimizer}: {why} couples the texels, refined with {optimizer} instead")
        objectives = ObjectiveFactory(cfg, inputs, init)
        history = refit(level, params, objectives, cfg, checkpoints)
        with torch.no_grad():
            pd, ps, sigma = (x.detach() for x in params.values())
            predicted = level.render(pd, ps, sigma).cpu()
    log(f"refinement ({optimizer}): loss {history[0]:.4g} -> {history[-1]:.4g} in {len(history)} evaluations")
    result = fit_result(pd, ps, sigma, predicted, history, seen, init, level, optimizer)
    if objectives.pooled is not None:
        result.coverage = torch.where(
            objectives.pooled & result.estimated, torch.full_like(result.coverage, COVER_MATERIAL), result.coverage
        )
    result.coverage = mark_untrusted(result.coverage, capture.untrusted)
    drop_misfits(result, capture, log)
    if capture.stats.get("preprocessing"):  # the geometry the level's choice rests on (geometry.median_size)
        result.model_reason += f"; geometry: {capture.stats['preprocessing']}"
    result.uncertainty = fit_uncertainty(cfg, level, result, stages)
    return result

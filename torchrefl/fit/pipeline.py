"""The fit of one capture at a chosen transport level.

local (Method I, Ch.3): classify observations, closed forms (eq. 3.3, 3.5), sigma search,
    interpolation, then the autograd refinement of the texel tensors with the local model.
auto: the cheapest level that explains the data (torchrefl.transport.select).
radiosity (Method II, Ch.4): form factors between texel patches (Embree), the closed-form inverse
    radiosity (eq. 4.7) for the patches' diffuse reflectance, the local closed forms on the
    intensities with the predicted diffuse interreflection removed (eq. 4.9-4.11), then the
    autograd refinement with the radiosity prediction (gradients through the linear solve).
photon (Method III, Ch.5): Method II's start (photon.start: radiosity, the default) or Method I's, then the outer
    loop of torchrefl.fit.photon_schedule: photons traced with the current parameters into a cache
    of indirect light per (light, texel), refit against local + cached indirect light, repeat.
"""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from torchrefl.core.brdf import classification_angle
from torchrefl.config import Config
from torchrefl.errors import ConfigError
from torchrefl.fit.classify import T_DIFF, class_counts, classify
from torchrefl.fit.diffuse_shape import fit_minnaert_exponent
from torchrefl.fit.emitter_fill import nearest_fitted
from torchrefl.fit.initialise import initialise_local
from torchrefl.fit.params import TexelParams
from torchrefl.fit.result import DiffuseModel, FitResult
from torchrefl.fit.refine import Objective, Prior, grid_neighbours, refine
from torchrefl.core.progress import bar
from torchrefl.transport.local import local_terms, predict
from torchrefl.transport.select import choose_level, predicted_interreflection_dn


def _to_device(terms, device):
    if device.type == "cpu":
        return terms
    return replace(terms, theta_h=terms.theta_h.to(device), cos_l=terms.cos_l.to(device), cos_v=terms.cos_v.to(device),
                   diffuse=terms.diffuse.to(device), specular=terms.specular.to(device))


def _with_emitters(fn, source):
    """fn(pd) evaluated with every texel's Pd taken from texel source[t] (fit.emitter_fill)."""
    return lambda pd: fn(pd[source.to(pd.device)])


def _radiosity_setup(cfg: Config, surface, obs, terms, cls, fit_mask, log):
    """Form factors, patch map and the Method II closed form; returns (patches, F, predict_indirect, note)."""
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.form_factors import form_factors_for_surface
    from torchrefl.transport.photon_level import apply_on_grid, light_sources, smoothing_matrix
    from torchrefl.transport.radiosity_level import (PatchMap, direct_irradiance, emitter_maps, indirect_irradiance,
                                                     inverse_radiosity)

    rc = cfg.radiosity
    tracer = RayTracer(surface.mesh_vertices, surface.mesh_faces, threads=cfg.threads)
    patches, F = form_factors_for_surface(surface, tracer, patch_size=rc.patch_size,
                                          samples_per_patch=rc.hemisphere_samples, seed=cfg.seed,
                                          split_angle_deg=rc.patch_split_angle_deg)
    pmap = PatchMap(patches.texel_patch, surface.areas.double(), patches.num_patches)
    F = F.to(obs.intensity.dtype)
    F_solve = None
    if rc.solve_samples is not None and rc.solve_samples != rc.hemisphere_samples:
        _, F_solve = form_factors_for_surface(surface, tracer, patch_size=rc.patch_size, samples_per_patch=rc.solve_samples,
                                              seed=cfg.seed + 1, split_angle_deg=rc.patch_split_angle_deg)
        F_solve = F_solve.to(obs.intensity.dtype)
    solver = {"method": rc.solver, "tol": rc.tolerance, "max_iter": rc.max_iterations, "direct_max": rc.direct_max}
    rho, det = inverse_radiosity(terms, obs.kappa, obs.intensity, (cls == T_DIFF) & fit_mask, pmap, F)
    nnz = lambda M: int(M._nnz()) if M.is_sparse else int((M != 0).sum())
    maps = None
    if obs.light_positions is not None and rc.light_maps > 1:
        sources = light_sources(surface, obs, rc.light_maps)
        if sources.num_maps > 1:                                       # the lights move with the scan
            maps = emitter_maps(sources, surface.positions, surface.normals, tracer, cfg.geometry.shadow_offset_mm,
                                obs.kappa)
    blocks = int(torch.unique(patches.block[:, 0] * (surface.grid_shape[1] + 1) + patches.block[:, 1]).numel())
    split = (f" ({patches.num_patches - blocks} more where a block straddles a crease of > {rc.patch_split_angle_deg:g} deg)"
             if patches.num_patches > blocks else "")
    note = (f"radiosity: {patches.num_patches} patches of {rc.patch_size}x{rc.patch_size} texels{split}, "
            f"{rc.hemisphere_samples} hemisphere rays each, {nnz(F)} non-zero form factors"
            + (f" (the solve's: {rc.solve_samples} rays, {nnz(F_solve)})" if F_solve is not None else "")
            + (f", {maps.weights.shape[0]} emitter maps per light" if maps is not None else "")
            + f"; inverse radiosity (eq. 4.7) determined {int(det.sum())} patches")
    smooth = rc.smoothing if rc.smoothing is not None else (rc.patch_size / 2.0 if rc.patch_size > 1 else 0.0)
    spread = lambda H: H
    reconstruct = None
    if rc.reconstruction == "linear" and rc.patch_size > 1:
        from torchrefl.transport.patch_reconstruction import linear_reconstruction
        reconstruct = linear_reconstruction(surface.texel_index.numpy(), surface.grid_shape, surface.positions.double().numpy(),
                                            surface.normals.double().numpy(), patches.texel_patch.numpy(),
                                            patches.centres.numpy(), patches.normals.numpy(), rc.patch_size,
                                            rc.patch_split_angle_deg)
        note += "; texel irradiance from a plane through the neighbouring patches' (radiosity.reconstruction)"
        if rc.smoothing is not None:
            log(f"radiosity.smoothing ({rc.smoothing:g}) is not used with radiosity.reconstruction: linear "
                "(set reconstruction: constant to spread patch values with it)")
    elif smooth > 0:
        note += f"; patch irradiance spread over the texels (std {smooth:g} texels)"
        M = smoothing_matrix(surface.texel_index.numpy(), surface.grid_shape, smooth, surface.normals.numpy(),
                             cfg.photon.smoothing_normal)
        spread = lambda H: apply_on_grid(M, H)
    indirect = lambda pd: spread(indirect_irradiance(terms, obs.kappa, pd, pmap, F, maps, F_solve,
                                                     reconstruct=reconstruct, **solver))

    def radiance(pd):
        """One radiosity solve for photon.specular_gather: (H, R, weights) with H (P, T, 3) what indirect(pd) gives,
        R (P, K, T, 3) every texel's outgoing all-diffuse radiance Pd (E + H) / pi with light p at map k's source,
        and the maps' (K, T) weights (K = 1 for static lights)."""
        H_maps = indirect_irradiance(terms, obs.kappa, pd, pmap, F, maps, F_solve, per_map=True,
                                     reconstruct=reconstruct, **solver)
        if maps is None:
            E, weights = direct_irradiance(terms, obs.kappa)[:, None], torch.ones(1, pd.shape[0], dtype=torch.float64)
        else:
            E, weights = maps.irradiance, maps.weights
        H = spread((H_maps * weights.to(H_maps.dtype)[None, :, :, None]).sum(1))     # = indirect(pd), same solve
        R = pd[None, None] * (E.to(H_maps.dtype) + spread(H_maps)) / math.pi
        return H, R, weights

    return pmap, F, solver, rho, det, indirect, radiance, note


def _photon_setup(cfg: Config, surface, obs, keep, device, dtype, radiosity_irradiance=None, radiosity_radiance=None,
                  emitter_source=None):
    """The PhotonLevel of this capture (tracer over the texel mesh, light sources); radiosity_irradiance: the
    radiosity level's H(pd) when photon.diffuse_paths is 'radiosity'; radiosity_radiance: its outgoing radiance
    per emitter map (_radiosity_setup), gathered when photon.specular_gather > 0."""
    from torchrefl.fit.photon_schedule import PhotonLevel
    from torchrefl.core.rays import RayTracer
    from torchrefl.transport.photon_level import light_sources
    from torchrefl.transport.photon_trace import PhotonTracer

    pc, rc = cfg.photon, cfg.reflectance
    tracer = RayTracer(surface.mesh_vertices, surface.mesh_faces, threads=cfg.threads)
    offset = 1e-3 * math.sqrt(float(surface.areas.double().median()))
    ptracer = PhotonTracer(tracer, surface.texel_index.numpy(), surface.positions.double().numpy(),
                           surface.normals.double().numpy(), rc.brdf, offset=offset,
                           min_bounces=pc.min_bounces, max_bounces=pc.max_bounces)
    sources = light_sources(surface, obs, pc.light_maps)
    view = obs.view_dirs_full() if obs.view_dir.dim() == 3 else obs.view_dir
    gather = None
    if pc.specular_gather > 0:
        if radiosity_radiance is None:
            raise ConfigError("photon.specular_gather > 0 needs photon.diffuse_paths: radiosity (the radiance it gathers)")
        from torchrefl.transport.specular_gather import SpecularGather
        gather = SpecularGather(ptracer, view.double().numpy(), keep.cpu().numpy(), rc.brdf, pc.specular_gather,
                                rc.min_cos_light, rc.sigma_max, seed=cfg.seed)
    return PhotonLevel(ptracer, sources, view.double(), keep, pc.photons_per_light, rc.sigma_max, rc.min_cos_light,
                       cfg.seed, dtype, device, smoothing=pc.smoothing,
                       grid=(surface.texel_index, surface.grid_shape, surface.normals.double()), smoothing_normal=pc.smoothing_normal,
                       specular_smoothing=pc.specular_smoothing,
                       linear_emitters=pc.linear_emitters, radiosity_irradiance=radiosity_irradiance,
                       specular_gather=gather, radiosity_radiance=radiosity_radiance if gather is not None else None,
                       emitter_source=emitter_source)


def fit_capture(cfg: Config, surface, obs, stages, log, device) -> FitResult:
    """Classify, initialise and refine at the transport level cfg.fit.model. Returns a dict of results."""
    rc, fc = cfg.reflectance, cfg.fit
    P = obs.num_lights
    bad = [i for i in fc.holdout if i >= P]
    if bad:
        raise ConfigError(f"fit.holdout: light indices {bad} out of range (the capture has {P} lights, indices 0..{P - 1})")
    if fc.model in ("radiosity", "photon") and not surface.has_mesh:
        raise ConfigError(f"fit.model: '{fc.model}' needs geometry with depth, but the capture {surface.source} has no "
                          "mesh (photometric stereo): use fit.model=local")
    if rc.diffuse != "lambert" and fc.model != "local" and surface.has_mesh:
        raise ConfigError(f"reflectance.diffuse: '{rc.diffuse}' is for local transport only, and fit.model '{fc.model}' "
                          f"may model the interreflection of {surface.source} (Lambertian): use fit.model=local or "
                          "reflectance.diffuse=lambert")
    held = torch.zeros(P, dtype=torch.bool)
    held[list(fc.holdout)] = True
    with stages.stage("precompute"):
        terms = local_terms(rc.brdf, surface.normals, obs)
        geometric_ok = obs.valid & (terms.cos_v > rc.min_cos_view) & (terms.cos_l > rc.min_cos_light)
        fit_mask = geometric_ok & ~held[:, None]
        eval_mask = geometric_ok & held[:, None]
        angle = terms.theta_h if rc.class_angle == "half" else classification_angle(
            rc.class_angle, surface.normals[None], obs.light_dir, obs.view_dirs_full())
        cls = classify(angle, fit_mask, rc.theta_diffuse_deg, rc.theta_specular_deg)
        counts = class_counts(cls)
        diffuse = DiffuseModel(rc.diffuse)
        if rc.diffuse == "minnaert":
            if rc.minnaert_k is None:
                shape = fit_minnaert_exponent(terms, obs.intensity, (cls == T_DIFF) & fit_mask)
                diffuse = DiffuseModel(rc.diffuse, shape.k, True, shape.as_dict())
                log(shape.note)
            else:
                diffuse = DiffuseModel(rc.diffuse, float(rc.minnaert_k), False)
                log(f"diffuse: Minnaert k = {rc.minnaert_k} (reflectance.minnaert_k)")
            terms = local_terms(rc.brdf, surface.normals, obs, diffuse_exponent=diffuse.k)
        level = fc.model
        reason = "fit.model is 'local': direct light with cast shadows"
        indirect = None
        choice = None
        if fc.model == "photon":
            reason = "fit.model is 'photon': direct light plus diffuse and specular interreflection by photon tracing"
        if fc.model == "auto" and not surface.has_mesh:
            choice = choose_level(False, None, None, None, fc.noise_floor_dn)
            level, reason = choice.level, choice.reason
        hybrid = cfg.photon.diffuse_paths == "radiosity"
        if level in ("radiosity", "auto") or (level == "photon" and (cfg.photon.start == "radiosity" or hybrid)):
            pmap, F, solver, rho_patch, rho_det, indirect, radiance, note = _radiosity_setup(cfg, surface, obs, terms, cls,
                                                                                            fit_mask, log)
            log(note)
            if level == "photon":
                reason += ("; started from Method II" if cfg.photon.start == "radiosity" else "; started from Method I") + (
                    "; all-diffuse paths from the radiosity solution" if hybrid else "") + " (" + note + ")"
            else:
                reason = "fit.model is 'radiosity': direct light plus diffuse interreflection (" + note + ")"
    init_kw = dict(ps_channels=rc.ps_channels, sigma_min=rc.sigma_min, sigma_max=rc.sigma_max, ps_max=rc.ps_max,
                   window=fc.interpolation_window, sigma_search=fc.sigma_search, specular=fc.specular)
    with stages.stage("initialise"):
        init = initialise_local(terms, obs.intensity, cls, counts["T_spec"], fit_mask, surface, **init_kw)
        emitter_source = None
        if level != "local" and surface.has_mesh and fc.emitter_fill == "nearest":
            emitter_source = nearest_fitted(surface.positions, init.defined)
            filled = int((emitter_source != torch.arange(surface.num_texels)).sum())
            if not filled:
                emitter_source = None
            else:
                log(f"interreflection: {filled} texels without a fitted observation reflect with the parameters of "
                    "the nearest fitted texel (fit.emitter_fill: nearest)")
                if indirect is not None:
                    indirect = _with_emitters(indirect, emitter_source)
                    radiance = _with_emitters(radiance, emitter_source)
        if level == "auto":
            diff_dn, spec_dn = predicted_interreflection_dn(terms, obs.kappa, init.pd.to(obs.intensity.dtype),
                                                            init.ps.to(obs.intensity.dtype), indirect, fit_mask)
            choice = choose_level(True, F, diff_dn, spec_dn, fc.noise_floor_dn, photon_available=True)
            level = choice.level
            reason = f"auto chose {level}: {choice.reason}"
            if level == "local":
                indirect = None
        if indirect is not None and not (level == "photon" and cfg.photon.start == "local"):
            # Method II: Pd of the patches from inverse radiosity where determined, the local closed
            # forms on the intensities without the predicted diffuse interreflection (eq. 4.9-4.11)
            pd0 = torch.where(rho_det[pmap.texel_patch][:, None], rho_patch[pmap.texel_patch].to(init.pd.dtype), init.pd)
            for _ in range(cfg.radiosity.init_passes):
                # then again from the closed forms' own Pd: each pass starts from a Pd with less interreflection in it
                # (at full size one pass left a start that the fit needed ~180 iterations to undo)
                with torch.no_grad():
                    H = indirect(pd0.to(obs.intensity.dtype))
                    direct_only = obs.intensity - (obs.kappa / math.pi) * pd0[None].to(H.dtype) * H
                init = initialise_local(terms, direct_only, cls, counts["T_spec"], fit_mask, surface, **init_kw)
                pd0 = init.pd
    log(init.note)
    log(f"transport level: {level} ({reason})")
    with stages.stage("fit"):
        dt = obs.intensity.dtype
        params = TexelParams(init.pd.to(dt), init.ps.to(dt), init.sigma.to(dt), rc.sigma_min, rc.sigma_max,
                             shared_specular=fc.specular == "shared", ps_max=rc.ps_max).to(device)
        dev_terms = _to_device(terms, device)
        local_model = lambda pd, ps, sg: predict(dev_terms, pd, ps, sg)
        if indirect is None or level == "photon":
            model = local_model
        else:
            kappa = obs.kappa.to(device)
            model = lambda pd, ps, sg: local_model(pd, ps, sg) + (kappa / math.pi) * pd[None] * indirect(pd)
        T = surface.num_texels
        # texels without specular evidence are pulled towards their interpolated lobe; a shared lobe has no
        # per-texel values to pull towards (the pull went to the unknown texels' floor values and, with few
        # highlights observed, collapsed the object's lobe to Ps ~ 0)
        prior_weight = 0.0 if fc.specular == "shared" else fc.prior_weight
        priors = [Prior((~init.known).to(device), init.ps.to(device), init.sigma.to(device), prior_weight)]
        if fc.specular == "pooled" and init.shared_lobe is not None:
            priors.append(Prior(torch.ones(T, dtype=torch.bool, device=device),
                                init.shared_lobe[0].expand(T, -1).to(device), init.shared_lobe[1].expand(T).to(device),
                                fc.pooling))
        neighbours = grid_neighbours(surface.texel_index, surface.grid_shape).to(device) if fc.smoothness > 0 else None
        intensity = obs.intensity.to(device)
        make_objective = lambda predict_fn, weight: Objective(
            predict=predict_fn, intensity=intensity, weight=weight.to(device), loss=fc.loss,
            loss_scale_8bit=fc.loss_scale_8bit, priors=priors, smoothness=fc.smoothness, neighbours=neighbours)
        photon = None
        if level == "photon":
            from torchrefl.fit.photon_schedule import run_schedule
            pc = cfg.photon
            plevel = _photon_setup(cfg, surface, obs, fit_mask | eval_mask, device, dt,
                                   radiosity_irradiance=indirect if hybrid else None,
                                   radiosity_radiance=radiance if hybrid else None, emitter_source=emitter_source)
            log(f"photon level: {plevel.sources.num_maps} photon map(s) per light, {pc.photons_per_light} photons "
                f"per light and refresh, {pc.outer_iterations} outer iterations, schedule {pc.schedule}, "
                + ("all-diffuse paths from the radiosity level, photons for the paths with a specular scattering"
                   if hybrid else "every path from photons") + f", Pd damping {pc.damping:g} between refreshes")

            def reinitialise(direct_only):
                fresh = initialise_local(terms, direct_only.cpu().to(obs.intensity.dtype), cls, counts["T_spec"],
                                         fit_mask, surface, **init_kw)
                priors[0] = Prior((~fresh.known).to(device), fresh.ps.to(device), fresh.sigma.to(device), prior_weight)
                return fresh.pd, fresh.ps, fresh.sigma

            photon = run_schedule(params, plevel, local_model, obs.kappa.to(device), make_objective, intensity,
                                  fit_mask, cls, schedule=pc.schedule, outer=pc.outer_iterations,
                                  optimizer=fc.optimizer, iterations=pc.iterations if pc.iterations is not None else fc.iterations,
                                  learning_rate=fc.learning_rate, progress=cfg.output.progress, log=log,
                                  reinitialise=reinitialise if pc.reinitialise else None, damping=pc.damping)
            model, history = photon["predict"], photon["history"] or [photon["scores"][0]]
        else:
            objective = make_objective(model, fit_mask)
            with bar(fc.iterations, f"fit ({fc.optimizer})", cfg.output.progress) as pb:
                history = refine(params, objective, fc.optimizer, fc.iterations, fc.learning_rate, progress=pb)
        with torch.no_grad():
            pd, ps, sigma = (x.detach() for x in params.values())
            pred = model(pd, ps, sigma).cpu()
            pd, ps, sigma = pd.cpu(), ps.cpu(), sigma.cpu()
    log(f"refinement ({fc.optimizer}): loss {history[0]:.4g} -> {history[-1]:.4g} in {len(history)} evaluations")
    return FitResult(
        pd=pd, ps=ps, sigma=sigma, predicted=pred, fit_mask=fit_mask, eval_mask=eval_mask, counts=counts,
        coverage=init.coverage, estimated=init.defined,
        init_counts={"pd_closed_form": int(init.pd_from_diffuse.sum()), "spec_closed_form": int(init.spec_closed_form.sum()),
                     "spec_known": int(init.known.sum())},
        history=history, level=level, model_reason=reason, diffuse=diffuse,
        model_numbers=choice.numbers if choice is not None else {},
        photon=None if photon is None else {"image_difference_per_refresh": photon["scores"],
                                            "kept_refresh": photon["best"], "cache": photon["cache"].stats},
    )

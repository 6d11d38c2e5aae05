"""Method II (dissertation Ch.4): direct light plus diffuse interreflection by radiosity.

prepare: form factors between texel patches (Embree), the patch map, emitter maps for co-rotating
lights and the patch-to-texel reconstruction. start: the closed-form inverse radiosity (eq. 4.7) for
the patches' Pd, then the local closed forms on the intensities minus the predicted interreflection
(eq. 4.9-4.11), INIT_PASSES times. predict: local + kappa Pd / pi * H(Pd), differentiable
through the linear solve.
"""

from __future__ import annotations

import copy
import math

import torch

from torchrefl.core.observation_classes import T_DIFF
from torchrefl.core.rays import RayTracer
from torchrefl.transport.form_factors import form_factors_for_surface
from torchrefl.transport.levels.base import IndirectTerms, LevelInputs, TransportLevel
from torchrefl.transport.light_maps import light_sources
from torchrefl.transport.patch_reconstruction import linear_reconstruction
from torchrefl.transport.radiosity import nonzeros, sparse_operator
from torchrefl.transport.radiosity_level import (
    DistinctEmitters,
    PatchMap,
    direct_irradiance,
    distinct_emitters,
    emitter_maps,
    indirect_irradiance,
    inverse_radiosity,
    reflected_indirect,
)
from torchrefl.transport.texel_model import SpecularEntries

#: a patch's texels stay within this angle of one another's normals: a block straddling a fold is split per side
#: (a shared patch gave Object E +3 % Pd within 2 mm of the fold: docs/results/object_e.md)
SPLIT_ANGLE_DEG = 30.0
#: passes of Method II's start; each starts from a Pd with less interreflection in it (1 pass left a start the fit
#: needed ~180 iterations to undo on Object E, 3 converge in 60)
INIT_PASSES = 3
#: the radiosity solve: direct LU up to 800 patches, the sparse fixed point above (relative tolerance, iteration cap)
SOLVER = {"method": "auto", "tol": 1e-7, "max_iter": 500, "direct_max": 800}
#: the density kernel's normal test (radians): neighbours across a fold or crease do not share irradiance
SMOOTHING_NORMAL = 0.1


class RadiosityLevel(TransportLevel):
    name = "radiosity"

    def __init__(self, inputs: LevelInputs):
        super().__init__(inputs)
        self.note = ""
        self.chosen_reason: str | None = None  # set when another rule (auto) chose this level
        self.emitter_source = None
        self._local = inputs.local_predict()

    @property
    def reason(self) -> str:
        if self.chosen_reason is not None:
            return self.chosen_reason
        return "fit.model is 'radiosity': direct light plus diffuse interreflection (" + self.note + ")"

    def prepare(self) -> None:
        inp, rc = self.inputs, self.inputs.cfg.radiosity
        cfg, surface, obs = inp.cfg, inp.surface, inp.obs
        tracer = RayTracer(surface.mesh_vertices, surface.mesh_faces, threads=cfg.threads)
        patches, F = form_factors_for_surface(
            surface,
            tracer,
            patch_size=rc.patch_size,
            samples_per_patch=rc.hemisphere_samples,
            seed=cfg.seed,
            split_angle_deg=SPLIT_ANGLE_DEG,
        )
        self.patches = PatchMap(patches.texel_patch, surface.areas.double(), patches.num_patches)
        self.F = sparse_operator(F, obs.intensity.dtype)
        self.F_solve = None
        if rc.solve_samples is not None and rc.solve_samples != rc.hemisphere_samples:
            _, F_solve = form_factors_for_surface(
                surface,
                tracer,
                patch_size=rc.patch_size,
                samples_per_patch=rc.solve_samples,
                seed=cfg.seed + 1,
                split_angle_deg=SPLIT_ANGLE_DEG,
            )
            self.F_solve = sparse_operator(F_solve, obs.intensity.dtype)
        self.solver = SOLVER
        self.maps = None
        if obs.light_positions is not None and rc.light_maps > 1:
            sources = light_sources(surface, obs, rc.light_maps)
            if sources.num_maps > 1:  # the lights move with the scan
                self.maps = emitter_maps(
                    sources, surface.positions, surface.normals, tracer, cfg.geometry.shadow_offset_mm
                )
        self.emitter_groups = self._distinct_emitters(inp)
        self._reconstruct = None
        self.note = self._describe(patches, rc) + self._reconstruction(patches)
        inp.log(self.note)

    def _describe(self, patches, rc) -> str:
        blocks = int(
            torch.unique(patches.block[:, 0] * (self.inputs.surface.grid_shape[1] + 1) + patches.block[:, 1]).numel()
        )
        split = (
            f" ({patches.num_patches - blocks} more where a block straddles a crease of > {SPLIT_ANGLE_DEG:g} deg)"
            if patches.num_patches > blocks
            else ""
        )
        self._rho, self._determined = inverse_radiosity(
            self.inputs.terms,
            self.inputs.obs.kappa,
            self.inputs.obs.intensity,
            (self.inputs.classes == T_DIFF) & self.inputs.fit_mask,
            self.patches,
            self.F,
        )
        return (
            f"radiosity: {patches.num_patches} patches of {rc.patch_size}x{rc.patch_size} texels{split}, "
            f"{rc.hemisphere_samples} hemisphere rays each, {nonzeros(self.F)} non-zero form factors"
            + (f" (the solve's: {rc.solve_samples} rays, {nonzeros(self.F_solve)})" if self.F_solve is not None else "")
            + (f", {self.maps.weights.shape[0]} emitter maps per light" if self.maps is not None else "")
            + (
                f"; {len(self.emitter_groups.inverse)} images share {len(self.emitter_groups.first)} direct "
                "irradiances (one solve each)"
                if self.emitter_groups is not None
                else ""
            )
            + f"; inverse radiosity (eq. 4.7) determined {int(self._determined.sum())} patches"
        )

    def _reconstruction(self, patches) -> str:
        """Texel irradiance from a plane through the neighbouring patches' (patches larger than one texel)."""
        s, size = self.inputs.surface, self.inputs.cfg.radiosity.patch_size
        if size == 1:
            return ""
        self._reconstruct = sparse_operator(
            linear_reconstruction(
                s.neighbours,
                s.positions.double().numpy(),
                s.normals.double().numpy(),
                patches.texel_patch.numpy(),
                patches.centres.numpy(),
                patches.normals.numpy(),
                size,
                SPLIT_ANGLE_DEG,
            ),
            self.inputs.obs.intensity.dtype,
        )
        return "; texel irradiance from a plane through the neighbouring patches' (radiosity.reconstruction)"

    def for_observations(self, inputs: LevelInputs) -> RadiosityLevel:
        """This prepared level on other observations of the same surface (relighting under a light the capture did
        not have, report.relight_indirect): the patches, form factors and reconstruction are the surface's and are
        shared; the emitter maps belong to the capture's moving lights and are dropped (one static light needs
        none)."""
        level = copy.copy(self)
        level.inputs = inputs
        level._local = inputs.local_predict()
        level.maps = None
        level.emitter_groups = level._distinct_emitters(inputs)
        return level

    def _distinct_emitters(self, inputs: LevelInputs) -> DistinctEmitters | None:
        """The images' distinct direct irradiances when some images share one (static lights photographed by
        several cameras), else None: one solve per image."""
        if self.maps is not None:
            return None
        emitters = distinct_emitters(inputs.terms, inputs.obs.kappa)
        return emitters if emitters.shared else None

    def use_emitters(self, source: torch.Tensor) -> None:
        self.emitter_source = source

    def _emitting(self, pd: torch.Tensor) -> torch.Tensor:
        return pd if self.emitter_source is None else pd[self.emitter_source.to(pd.device)]

    def indirect(self, pd: torch.Tensor, per_map: bool = False) -> torch.Tensor:
        """(P, T, 3) diffuse interreflected irradiance H at every texel for texel Pd (T, 3); per_map: (P, K, T, 3)
        before the interpolation between emitter maps and the spread over the texel grid."""
        H = indirect_irradiance(
            self.inputs.terms,
            self.inputs.obs.kappa,
            self._emitting(pd),
            self.patches,
            self.F,
            self.maps,
            self.F_solve,
            per_map=per_map,
            reconstruct=self._reconstruct,
            emitters=self.emitter_groups,
            **self.solver,
        )
        return H

    def radiance(self, pd: torch.Tensor):
        """One solve for photon.specular_gather: (H, R, weights) with H (P, T, 3) what indirect(pd) gives, R
        (P, K, T, 3) every texel's outgoing all-diffuse radiance Pd (E + H) / pi with light p at map k's source,
        and the maps' (K, T) weights (K = 1 for static lights)."""
        pd = self._emitting(pd)
        H_maps = indirect_irradiance(
            self.inputs.terms,
            self.inputs.obs.kappa,
            pd,
            self.patches,
            self.F,
            self.maps,
            self.F_solve,
            per_map=True,
            reconstruct=self._reconstruct,
            emitters=self.emitter_groups,
            **self.solver,
        )
        if self.maps is None:
            E = direct_irradiance(self.inputs.terms, self.inputs.obs.kappa)[:, None]
            weights = torch.ones(1, pd.shape[0], dtype=torch.float64)
        else:
            E, weights = self.maps.irradiance, self.maps.weights
        H = (H_maps * weights.to(H_maps.dtype)[None, :, :, None]).sum(1)
        R = pd[None, None] * (E.to(H_maps.dtype) + H_maps) / math.pi
        return H, R, weights

    def start(self, init):
        """Method II's start: the patches' Pd from eq. 4.7 where determined, then the local closed forms on the
        intensities without the interreflection predicted from the previous pass's Pd (eq. 4.9-4.11)."""
        obs, texel_patch = self.inputs.obs, self.patches.texel_patch
        pd0 = torch.where(self._determined[texel_patch][:, None], self._rho[texel_patch].to(init.pd.dtype), init.pd)
        for _ in range(INIT_PASSES):
            with torch.no_grad():
                H = self.indirect(pd0.to(obs.intensity.dtype))
                direct_only = obs.intensity - reflected_indirect(obs.kappa, pd0, H)
            init = self.inputs.initialise(direct_only)
            pd0 = init.pd
        return init

    def predict(self, pd, ps, sigma):
        kappa = self.inputs.obs.kappa.to(pd.device)
        return self._local(pd, ps, sigma) + reflected_indirect(kappa, pd, self.indirect(pd))

    def indirect_terms(self, pd: torch.Tensor) -> IndirectTerms:
        kappa = self.inputs.obs.kappa.to(pd.device)
        with torch.no_grad():
            diffuse = reflected_indirect(kappa, torch.ones_like(pd), self.indirect(pd))
        zero = torch.zeros_like(diffuse)
        return IndirectTerms(
            diffuse, lambda sigma: zero, entries_of=lambda texels: SpecularEntries.empty(zero.dtype, zero.device)
        )

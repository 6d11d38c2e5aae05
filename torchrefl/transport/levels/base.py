"""The interface every transport level implements, and what a level is built from.

A level (local, radiosity, photon; transport/levels/) turns texel parameters into predicted images.
The fit (torchrefl.fit.pipeline) drives every level through the same loop:

    level.prepare()                       precompute for this capture (form factors, tracers, ...)
    init = level.start(init)              correct the closed-form start (Method II's passes)
    level.refresh(params, 0)              outer-iteration state (the photon cache)
    for k in range(level.refits):
        re-estimate with level.indirect_terms  texels with specular evidence: the sigma search on direct + indirect
        for step in level.steps(k):       which parameters are refit on which observations
            refine(params, objective(level.predict, step.mask), ...)
        stop if level.converged(params)   (before the refresh: no trace for parameters that did not move)
        level.refresh(params, k + 1)
    level.finish(params)                  keep the best refresh (photon)

Adding a level is one module with a TransportLevel subclass; `auto` chooses among level objects
(torchrefl.transport.levels.auto).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Optional

import torch

from torchrefl.config import Config
from torchrefl.core.observations import Observations
from torchrefl.core.surface import Surface
from torchrefl.transport.local import LocalTerms, predict
from torchrefl.transport.texel_model import SpecularEntries, TexelModel

#: LocalTerms' tensors, in their constructor's order
LOCAL_TENSORS = ("theta_h", "cos_l", "cos_v", "diffuse", "specular")


@dataclass
class LevelInputs:
    """The capture as every level sees it: the local model's terms and the observation masks.

    initialise(intensity (P, T, 3)) -> the closed-form start (Pd, Ps, sigma and what it knew) on these
    intensities: a level that removes its predicted interreflection restarts the closed forms with it.
    """

    cfg: Config
    surface: Surface
    obs: Observations
    terms: LocalTerms
    classes: torch.Tensor  # (P, T) observation classes
    fit_mask: torch.Tensor  # (P, T) fitted observations
    eval_mask: torch.Tensor  # (P, T) held-out observations
    device: torch.device
    log: Callable[[str], None]
    initialise: Callable[[torch.Tensor], Any]
    #: the local fit's per-texel stages run in these chunks of texels (torchrefl.fit.texel_chunks; None: at once)
    chunks: Optional[list] = None

    def local_terms(self, texels: Optional[torch.Tensor] = None) -> LocalTerms:
        """The local terms on the fit's device; texels (n,) long: of those texels only."""
        terms = self.terms if texels is None else self.terms.texels(texels)
        if self.device.type != "cpu":
            terms = LocalTerms(
                terms.brdf,
                *(getattr(terms, k).to(self.device) for k in LOCAL_TENSORS),
                terms.diffuse_exponent,
                None if terms.spread is None else terms.spread.to(self.device),
            )
        return terms

    def local_predict(self, texels: Optional[torch.Tensor] = None) -> Callable:
        """(pd, ps, sigma) -> (P, T, 3) direct light on the fit's device; texels (n,) long: of those texels only,
        taking and giving their rows."""
        terms = self.local_terms(texels)
        return lambda pd, ps, sigma: predict(terms, pd, ps, sigma)


@dataclass
class IndirectTerms:
    """A level's indirect light at the current parameters as linear factors of each texel's own Pd and Ps:
    diffuse (P, T, 3), the sensor value per unit Pd; specular(sigma) -> (P, T, 3), the sensor value per
    unit Ps with every texel's lobe at sigma (a 0-d tensor, or (T,) one value per texel). Held fixed while one
    texel's parameters vary."""

    diffuse: torch.Tensor
    specular: Callable[[torch.Tensor], torch.Tensor]
    #: index (n,) long -> the specular factor of those texels only, sigma (n,) -> (P, n, 3) (None: specular sliced)
    specular_of: Optional[Callable[[torch.Tensor], Callable[[torch.Tensor], torch.Tensor]]] = None
    #: index (n,) long -> the specular factor of those texels as SpecularEntries (None: not of that form)
    entries_of: Optional[Callable[[torch.Tensor], SpecularEntries]] = None

    def texels(self, index: torch.Tensor) -> "IndirectTerms":
        """The terms of the texels index (n,) long only; their specular factor takes sigma per texel of the subset
        ((n,) or 0-d). Without specular_of the full factor is evaluated and sliced (the other texels at the
        subset's mean sigma: a texel's factor depends on its own sigma only)."""
        index = index.to(self.diffuse.device)
        diffuse = self.diffuse.index_select(1, index)
        entries_of = None if self.entries_of is None else (lambda sub: self.entries_of(index.index_select(0, sub)))
        if self.specular_of is not None:
            return IndirectTerms(diffuse, self.specular_of(index), entries_of=entries_of)
        T, full = self.diffuse.shape[1], self.specular

        def specular(sigma: torch.Tensor) -> torch.Tensor:
            sigma = torch.as_tensor(sigma, dtype=diffuse.dtype, device=diffuse.device)
            if sigma.dim():
                sigma = sigma.mean().expand(T).index_put((index,), sigma)
            return full(sigma).index_select(1, index)

        return IndirectTerms(diffuse, specular, entries_of=entries_of)


@dataclass
class RefitStep:
    """One refinement within an outer iteration: the raw tensors trained (None = all) on which observations."""

    train: Optional[list]
    mask: torch.Tensor
    label: str
    iterations: int


class TransportLevel(ABC):
    """A transport level: precompute, predict (differentiably), correct the start, refresh between refits."""

    name: ClassVar[str]
    #: outer iterations: refits separated by refreshes (1 for levels without an outer loop)
    refits: int = 1

    def __init__(self, inputs: LevelInputs):
        self.inputs = inputs
        self.model_numbers: dict = {}  # the measurements behind auto's choice (metrics.json model_numbers)

    def prepare(self) -> None:
        """Precompute what the level needs for this capture (called once, before the start)."""

    @property
    @abstractmethod
    def reason(self) -> str:
        """The sentence this level contributes to metrics.json's model_reason."""

    def use_emitters(self, source: torch.Tensor) -> None:
        """Texels without a fitted observation reflect with the parameters of texel source[t] (fit.emitter_fill)."""

    def start(self, init):
        """The start corrected for what this level models (default: the closed forms as they are)."""
        return init

    @abstractmethod
    def predict(self, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """(P, T, 3) predicted images for texel parameters (differentiable in all three)."""

    def steps(self, k: int) -> list[RefitStep]:
        """The refinements of outer iteration k (default: all parameters on every fitted observation)."""
        fc = self.inputs.cfg.fit
        return [RefitStep(None, self.inputs.fit_mask, f"fit ({fc.optimizer})", fc.iterations)]

    def indirect_terms(self, pd: torch.Tensor) -> Optional[IndirectTerms]:
        """The indirect light this level predicts at texel Pd (T, 3), as IndirectTerms (default: none)."""
        return None

    def texel_model(self, pd: torch.Tensor, texels: Optional[torch.Tensor] = None) -> Optional[Callable]:
        """(pd, ps, sigma) -> (P, T, 3): predict with the indirect light held at texel Pd `pd` (indirect_terms), so
        that each texel's images depend on its own parameters only; equals predict at pd (the per-texel solver's
        model, torchrefl.fit.texel_lm). texels: (n,) long, the model of those texels only, taking and giving their
        rows ((n, 3), ... -> (P, n, 3)); None where the level cannot give it (no indirect terms: predict is texel by
        texel but need not be the local model, unless the level says so by overriding this). A TexelModel, in
        parts, where the level has indirect terms."""
        terms = self.indirect_terms(pd)
        if terms is None:  # no indirect light: predict itself is texel by texel
            return self.predict if texels is None else None
        if texels is not None:
            terms = terms.texels(texels)
        entries_of, n = terms.entries_of, terms.diffuse.shape[1]
        entries = None
        if entries_of is not None:
            entries = lambda: entries_of(torch.arange(n, device=terms.diffuse.device))  # noqa: E731
        return TexelModel(self.inputs.local_terms(texels), terms.diffuse, terms.specular, entries)

    def refresh(self, params, k: int) -> None:
        """Update the level's state for the parameters after k refits (default: nothing to refresh)."""

    def converged(self, params) -> Optional[str]:
        """After each refit, before its refresh: why the outer loop may stop here (None: go on; the default: run
        all `refits`)."""
        return None

    def finish(self, params) -> None:
        """Called after the last refit (default: nothing)."""

    def prediction_variance(self) -> Optional[torch.Tensor]:
        """(3,) float64 the variance, in DN^2 per observation and channel, of the Monte Carlo noise in the level's
        predictions at the kept parameters, after finish (None: exact predictions, the default)."""
        return None

    def state(self) -> dict:
        """What refresh() keeps between outer iterations, for a checkpoint (default: nothing)."""
        return {}

    def restore(self, state: dict) -> None:
        """Put back what state() returned (a resumed fit continues after the outer iteration it was saved at)."""

    def render(self, pd: torch.Tensor, ps: torch.Tensor, sigma: torch.Tensor) -> torch.Tensor:
        """(P, T, 3) the final predicted images of the fitted parameters: the held-out and re-rendered images
        (default: predict)."""
        return self.predict(pd, ps, sigma)

    def report(self) -> dict | None:
        """The level's own block for metrics.json (None: none)."""
        return None

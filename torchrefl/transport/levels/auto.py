"""fit.model: the level a config names, or `auto`: the cheapest level that explains the data.

auto prepares the radiosity level (its form factors tell whether texels see one another), predicts the
diffuse and specular interreflection at the closed-form start, and keeps the cheapest level whose
neglected light stays below fit.noise_floor_dn (the rules: torchrefl.transport.select).
"""

from __future__ import annotations

from torchrefl.errors import ConfigError
from torchrefl.transport.levels.base import LevelInputs, TransportLevel
from torchrefl.transport.levels.local import LocalLevel
from torchrefl.transport.levels.photon import PhotonLevel
from torchrefl.transport.levels.radiosity import RadiosityLevel
from torchrefl.transport.memory_estimate import check_level_memory
from torchrefl.transport.select import choose_level, predicted_interreflection_dn


def check_level(model: str, inputs: LevelInputs) -> None:
    """Refuse a level the capture or the reflectance model cannot support, naming the key."""
    surface, rc = inputs.surface, inputs.cfg.reflectance
    if model in ("radiosity", "photon") and not surface.has_mesh:
        raise ConfigError(
            f"fit.model: '{model}' needs geometry with depth, but the capture {surface.source} has no "
            "mesh (photometric stereo): use fit.model=local"
        )
    if rc.diffuse != "lambert" and model != "local" and surface.has_mesh:
        raise ConfigError(
            f"reflectance.diffuse: '{rc.diffuse}' is for local transport only, and fit.model '{model}' "
            f"may model the interreflection of {surface.source} (Lambertian): use fit.model=local or "
            "reflectance.diffuse=lambert"
        )


def named_level(inputs: LevelInputs) -> TransportLevel:
    """The level fit.model names (auto: a RadiosityLevel to choose from, or local without depth)."""
    model = inputs.cfg.fit.model
    check_level(model, inputs)
    if model == "local":
        return LocalLevel(inputs)
    if model == "auto":
        if not inputs.surface.has_mesh:
            choice = choose_level(False, None, None, None, inputs.cfg.fit.noise_floor_dn)
            level = LocalLevel(inputs, choice.reason)
            level.model_numbers = choice.numbers
            return level
        return RadiosityLevel(inputs)
    if model == "radiosity":
        return RadiosityLevel(inputs)
    return PhotonLevel(inputs, RadiosityLevel(inputs))


def prepare(level: TransportLevel) -> None:
    """Precompute a level and the radiosity level it composes, once its memory estimate fits (MemoryLimitError)."""
    check_level_memory(level)
    if isinstance(level, PhotonLevel):
        level.radiosity.prepare()
    level.prepare()


def choose(radiosity: RadiosityLevel, init) -> TransportLevel:
    """auto's choice at the closed-form start `init`, among local, the prepared radiosity level and photon."""
    inp = radiosity.inputs
    dtype = inp.obs.intensity.dtype
    diff_dn, spec_dn = predicted_interreflection_dn(
        inp.terms, inp.obs.kappa, init.pd.to(dtype), init.ps.to(dtype), radiosity.indirect, inp.fit_mask
    )
    choice = choose_level(True, radiosity.F, diff_dn, spec_dn, inp.cfg.fit.noise_floor_dn, photon_available=True)
    reason = f"auto chose {choice.level}: {choice.reason}"
    if choice.level == "local":
        level = LocalLevel(inp, reason)
    elif choice.level == "radiosity":
        radiosity.chosen_reason = reason
        level = radiosity
    else:
        level = PhotonLevel(inp, radiosity, reason)
        if radiosity.emitter_source is not None:
            level.use_emitters(radiosity.emitter_source)
    level.model_numbers = choice.numbers
    return level

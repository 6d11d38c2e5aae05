"""The refinement's state between outer iterations, as a checkpoint holds it (torchrefl.core.checkpoints).

After the first refresh and after each outer iteration k the fit can stop and continue later from: the texel
parameters, the objective's lobe priors (moved by the re-estimations), the loss history, the transport level's
own state (TransportLevel.state: the photon caches, scores and best refresh) and torch's random state. The
optimisers start anew at every refit step (torchrefl.fit.refine), so none of their state crosses an outer
iteration.
"""

from __future__ import annotations

import torch

from torchrefl.core.params import TexelParams
from torchrefl.transport.levels.base import TransportLevel

#: the checkpoints of the fit: the level's corrected start, and the refinement after its latest outer iteration
INITIALISE = "initialise"
OUTER = "outer"


def outer_state(
    done: int, level: TransportLevel, params: TexelParams, objective, history: list[float], memory=None
) -> dict:
    """The refinement after `done` outer iterations (0: after the first refresh). `objective` is the fit's objective
    factory; its lobe priors are kept when it has them (state()); memory: the indirect terms the last re-estimation
    saw (torchrefl.fit.outer_skip.IndirectMemory, or None)."""
    return {
        "reestimate_memory": memory,
        "done": done,
        "level": level.name,
        "params": {n: p.detach().clone() for n, p in params.named_parameters()},
        "objective": objective.state() if hasattr(objective, "state") else None,
        "history": list(history),
        "level_state": level.state(),
        "rng": torch.get_rng_state(),
    }


def restore_outer(state: dict, level: TransportLevel, params: TexelParams, objective) -> tuple[list[float], int]:
    """Put a saved refinement state back into the level, the parameters and the objective factory; returns the
    loss history so far and the number of outer iterations done (the re-estimation's memory: saved_memory)."""
    with torch.no_grad():
        for n, p in params.named_parameters():
            p.copy_(state["params"][n].to(p))
    if state["objective"] is not None:
        objective.restore(state["objective"])
    level.restore(state["level_state"])
    torch.set_rng_state(state["rng"])
    return list(state["history"]), int(state["done"])


def saved_memory(state: dict | None):
    """The re-estimation's memory a saved refinement state holds (None: none, or a checkpoint from before it)."""
    return None if state is None else state.get("reestimate_memory")

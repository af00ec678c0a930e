"""``train --init-weights``: start a run from another run's weights, where the two networks allow it.

A run may start from weights of the same network, or of a network that the run's adds modules to which start as the
identity (context convolutions, a full-resolution refinement, a centre branch, a vote head), so that the run starts
from exactly what the weights computed. One widening changes the centre head itself: weights with **one shared centre
channel** (a DIMO network) may start a run with a **factored** centre head of one channel per object id (BOP layouts,
the multi-sensor bins). The factored head's class-agnostic centre logit takes the shared channel's weights and its
class logits start at zero (every id equally likely), so channel ``k`` starts as ``sigmoid(center) / K``: the DIMO
network's centres, to be told apart by training. Why: the synthetic industrial bins pile DIMO's parts, and a network
trained from scratch on their 480 views reached bop25_mAP 0.185 after 30 epochs (``results/accuracy/industrial``),
while the shipped DIMO network already finds these parts' centres in other looks.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from bop_cender.errors import ConfigError
from bop_cender.net.unet import UNet, UNetSpec
from bop_cender.net.weights import load_weights

#: The modules a run may add to the init weights' network: each starts as the identity.
NEW_MODULES = ("context.", "refine.", "center_branch.", "vote_head.")
#: The centre head's output convolution (``_Head.body[-1]``), the one a widening changes.
CENTER_OUTPUT = "center_head.body.6."


def start_from(model: UNet, path: str | Path, channel_obj_ids: tuple[int, ...] | None) -> None:
    """Load the weights at ``path`` into ``model`` (the run's network, its centre channels of ``channel_obj_ids``:
    None for one shared channel).

    Raises:
        ConfigError: the weights cannot start this network (another architecture, other object ids per channel),
            naming the file and ``--init-weights``.
    """
    init = load_weights(path, field="--init-weights")
    spec, init_spec = model.spec, init.model.spec
    widening = widens_centers(init_spec, spec)
    if not (widening or can_start_from(init_spec, spec)):
        hint = ""
        if widens_centers(
            init_spec, replace(spec, factored_centers=True, center_channels=max(2, spec.center_channels))
        ):
            hint = "; weights of one shared center channel start a run with --factored-centers"
        raise ConfigError(
            f"its network ({init_spec.name}, {init_spec.center_channels} center channels) is not"
            f" this run's ({spec.name}, {spec.center_channels}){hint}",
            file=path,
            field="--init-weights",
        )
    if not widening and init.channel_obj_ids != channel_obj_ids:
        raise ConfigError(
            f"its center channels are of object ids {ids_text(init.channel_obj_ids)}; this run's data has"
            f" {ids_text(channel_obj_ids)}",
            file=path,
            field="--init-weights",
        )
    state = init.model.state_dict()
    if widening:
        state = _widened_center_output(state, model.state_dict())
    missing, unexpected = model.load_state_dict(state, strict=False)
    assert not unexpected and all(k.startswith(NEW_MODULES) for k in missing), (missing, unexpected)


def can_start_from(init: UNetSpec, spec: UNetSpec) -> bool:
    """Whether weights of network ``init`` can start a run of ``spec``: the same network, or ``spec`` adds context
    convolutions, a full-resolution refinement, a centre branch and/or a vote head to it (all start as the identity,
    so the run starts from exactly what ``init`` computed)."""
    if init == spec:
        return True
    base = replace(spec, name=init.name)
    if not init.context_dilations:
        base = replace(base, context_dilations=())
    if not init.refine_channels:
        base = replace(base, refine_channels=0)
    if not init.center_branch_channels:
        base = replace(base, center_branch_channels=0)
    if not init.center_votes:  # a new vote head: no pixel votes at first, so the maps are the head's
        base = replace(base, center_votes=False, vote_sigma_px=init.vote_sigma_px, vote_mix=init.vote_mix)
    return base == init


def widens_centers(init: UNetSpec, spec: UNetSpec) -> bool:
    """Whether ``spec`` is ``init`` (one shared centre channel) with a factored centre head of several channels
    (and, as :func:`can_start_from` allows, modules added that start as the identity)."""
    if init.center_channels != 1 or init.factored_centers or not spec.factored_centers:
        return False
    return can_start_from(init, replace(spec, center_channels=1, factored_centers=False))


def ids_text(ids: tuple[int, ...] | None) -> str:
    """Centre channels' object ids for a message: ``[1, 2, 3]`` or ``none (one shared channel)``."""
    return "none (one shared channel)" if ids is None else str(list(ids))


def _widened_center_output(init: dict[str, torch.Tensor], target: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """``init``'s state with the centre output convolution (weight ``(1, c, 1, 1)``, bias ``(1,)``) widened to the
    factored head's ``(1 + K, c, 1, 1)``: the centre logit as it was, the K class logits zero."""
    state = dict(init)
    for name in ("weight", "bias"):
        key = CENTER_OUTPUT + name
        widened = torch.zeros_like(target[key])
        widened[:1] = init[key]
        state[key] = widened
    return state

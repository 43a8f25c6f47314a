"""Freeze masks, the masked optimizer, and the PTRL transfer (paper Eq. 4-5, Algorithm 1).

A freeze mask is a pytree shaped like the parameters whose leaves are bool arrays of the
parameter's own shape (True = frozen). Array leaves, not Python bools, let every freeze
variant share one compiled program under ``vmap``, and per-unit masks (a fraction of a layer)
need no new code.

Freezing under Adam takes three guards, each of which alone is not enough:
1. gradients of frozen leaves are zeroed *before* the inner transform, so global-norm clipping
   does not count them;
2. the final directions of frozen leaves are zeroed, so non-zero moments (restored from
   pretraining, say) cannot move them;
3. frozen leaves' moments are carried over untouched: a frozen leaf keeps no moving state.
``jnp.where`` is used throughout rather than ``g * mask``, since NaN * 0 is NaN.
"""

from __future__ import annotations

import math
from typing import Mapping

import jax
import jax.numpy as jnp

from ptrl_jax.core.optim import Optimizer
from ptrl_jax.core.types import Mask, Params

# The paper's transferable hidden layers, by name (rsl_rl's actor.2 and actor.4).
HIDDEN_LAYERS: dict[str, str] = {"L1": "layer_1", "L2": "layer_2"}


TRANSFER_MODES = ("paper", "semantic", "semantic_actor", "semantic_input", "semantic_output")
"""How a transferring variant initialises the target: ``paper`` copies the actor's L1 and L2
(``transfer`` below); ``semantic`` maps the whole agent through the robots' declarations
(``ptrl_jax.core.semantic``); ``semantic_actor`` maps the actor, its log-std and the normaliser the
same way but starts the critic fresh, as the paper does (a critic's values are in the source's
reward scale and dynamics, which the target may not share; docs/table4.md); ``semantic_input``
maps only what the actor reads (its input layer and the normaliser) and copies its hidden layers,
and starts its output layer, log-std and critic fresh: the paper's transfer with a mapped input
layer, which carries the source's features but not its joint commands (docs/transfer.md);
``semantic_output`` is its complement: the actor's input layer and the normaliser start fresh,
the hidden layers are copied, and the output layer and log-std are mapped (critic fresh): the
paper's transfer with a mapped output layer."""
MODE_SEPARATOR = "@"
"""Variant names ``<preset>@semantic`` (``L2@semantic``, ``rho0.5@semantic``) or
``<preset>@semantic_actor``, ``<preset>@semantic_input`` or ``<preset>@semantic_output`` transfer
semantically; a bare name transfers as the paper does."""


class FreezePreset:
    """What a target variant transfers and what it freezes: the first ``ceil(ratio * n)`` output
    units of each layer in ``frozen`` (``ratio`` 1: the whole layer, the paper's presets), after
    a ``mode`` transfer (``paper`` or ``semantic``; ignored when ``transfer`` is False)."""

    def __init__(self, name: str, transfer: bool, frozen: tuple[str, ...], ratio: float = 1.0,
                 mode: str = "paper"):
        self.name, self.transfer, self.frozen, self.ratio, self.mode = name, transfer, frozen, ratio, mode

    @property
    def mode_index(self) -> int:
        """0: no transfer (scratch), 1: paper, 2: semantic, 3: semantic_actor, 4: semantic_input,
        5: semantic_output (the program's per-variant switch)."""
        return 0 if not self.transfer else 1 + TRANSFER_MODES.index(self.mode)

    def __repr__(self) -> str:
        return (f"FreezePreset({self.name!r}, transfer={self.transfer}, frozen={self.frozen}, "
                f"ratio={self.ratio}, mode={self.mode!r})")


FREEZE_PRESETS: Mapping[str, FreezePreset] = {
    "none": FreezePreset("none", transfer=True, frozen=()),
    "L1": FreezePreset("L1", transfer=True, frozen=("L1",)),
    "L2": FreezePreset("L2", transfer=True, frozen=("L2",)),
    "L1+L2": FreezePreset("L1+L2", transfer=True, frozen=("L1", "L2")),
    "scratch": FreezePreset("scratch", transfer=False, frozen=()),
}


RATIO_PREFIX = "rho"
"""Variant names ``rho<r>`` (``rho0.25``) are continuous freeze ratios; see ``ratio_preset``."""


def ratio_name(rho: float) -> str:
    """The variant name of freeze ratio ``rho``: 0.25 -> 'rho0.25'."""
    return f"{RATIO_PREFIX}{float(rho):g}"


def ratio_preset(rho: float) -> FreezePreset:
    """Freeze ratio ``rho`` in [0, 1]: transfer L1 and L2, then freeze the first ``ceil(rho n)``
    of the n output units of each (their weight columns and biases), the rest fine-tuned.

    Every transferred layer then has the same frozen share, ceil(rho n) / n, so the frozen
    fraction of the transferable parameters is rho up to rounding (exactly rho when rho n is an
    integer for both layers, as for the quarters with 256 and 128 units): rho = 0 is the 'none'
    preset and rho = 1 is 'L1+L2'. A frozen unit keeps the source's feature of its inputs;
    freezing output units (not input rows) keeps whole features, which is what a transferred
    prior is made of, and keeps the next layer's inputs from those units stable.
    """
    rho = float(rho)
    if not 0.0 <= rho <= 1.0:
        raise ValueError(f"freeze ratio must be in [0, 1], got {rho}")
    return FreezePreset(ratio_name(rho), transfer=True, frozen=("L1", "L2"), ratio=rho)


def frozen_share(preset: FreezePreset, actor_hidden: tuple[int, ...] = (512, 256, 128)) -> float:
    """The frozen fraction of L1's and L2's parameters (weights and biases) under ``preset``,
    with the actor's hidden sizes ``actor_hidden``: the x axis on which whole-layer presets and
    freeze ratios share one curve. With (512, 256, 128): 'L2' is 0.2003, 'L1' 0.7997, ``rho0.5``
    0.5; 'none' and 'scratch' are 0."""
    h0, h1, h2 = actor_hidden
    units = {"L1": (h1, h0 + 1), "L2": (h2, h1 + 1)}  # (output units, parameters per unit)
    total = sum(n * per for n, per in units.values())
    frozen = sum(math.ceil(preset.ratio * units[layer][0]) * units[layer][1] for layer in preset.frozen)
    return frozen / total


def is_semantic(name: str) -> bool:
    """Whether variant ``name`` transfers semantically (``<preset>@semantic``, ``@semantic_actor``,
    ``@semantic_input`` or ``@semantic_output``)."""
    return name.partition(MODE_SEPARATOR)[2].startswith("semantic")


def with_mode(name: str, mode: str) -> str:
    """The variant name of ``name`` transferred in ``mode``: ``('L2', 'semantic')`` ->
    'L2@semantic'; paper-mode and non-transferring names stay bare."""
    base = name.partition(MODE_SEPARATOR)[0]
    if mode == "paper" or not variant(base).transfer:
        return base
    return f"{base}{MODE_SEPARATOR}{mode}"


def variant(name: str) -> FreezePreset:
    """The preset named ``name``: one of FREEZE_PRESETS, or ``rho<r>`` for a freeze ratio,
    optionally suffixed ``@semantic`` (or ``@paper``) for its transfer mode."""
    base, sep, mode = name.partition(MODE_SEPARATOR)
    if sep:
        if mode not in TRANSFER_MODES:
            raise ValueError(f"variant {name!r}: unknown transfer mode {mode!r}; choose from {list(TRANSFER_MODES)}")
        v = variant(base)
        if not v.transfer:
            raise ValueError(f"variant {name!r}: {base!r} transfers nothing, so it takes no transfer mode")
        return FreezePreset(name if mode != "paper" else base, v.transfer, v.frozen, v.ratio, mode)
    if name in FREEZE_PRESETS:
        return FREEZE_PRESETS[name]
    if name.startswith(RATIO_PREFIX):
        try:
            rho = float(name[len(RATIO_PREFIX):])
        except ValueError:
            rho = None
        if rho is not None:
            return ratio_preset(rho)
    raise ValueError(f"unknown freeze preset {name!r}; choose from {list(FREEZE_PRESETS)} "
                     f"or {RATIO_PREFIX}<r> with r in [0, 1]")


def _path_names(path) -> tuple[str, ...]:
    return tuple(str(getattr(k, "key", getattr(k, "name", k))) for k in path)


def empty_mask(params: Params) -> Mask:
    return jax.tree.map(lambda p: jnp.zeros(p.shape, bool), params)


def layer_mask(params: Params, layers: tuple[str, ...], ratio: float = 1.0) -> Mask:
    """Mask that freezes the leaves under ``actor/<layer>`` for the given paper layer names:
    all of them (``ratio`` 1), or the first ``ceil(ratio * n)`` of the layer's n output units
    (weight columns ``w[:, :k]`` and biases ``b[:k]``)."""
    unknown = [layer for layer in layers if layer not in HIDDEN_LAYERS]
    if unknown:
        raise ValueError(f"unknown layer(s) {unknown}; transferable layers are {list(HIDDEN_LAYERS)}")
    names = {HIDDEN_LAYERS[layer] for layer in layers}

    def leaf(path, p):
        parts = _path_names(path)
        frozen = len(parts) >= 2 and parts[0] == "actor" and parts[1] in names
        if not frozen or ratio >= 1.0:
            return jnp.full(p.shape, frozen, bool)
        units = p.shape[-1]  # w: [in, out], b: [out]
        k = math.ceil(ratio * units - 1e-9)  # tolerate float noise: 0.3 * 10 is 3.0000000000000004
        return jnp.broadcast_to(jnp.arange(units) < k, p.shape)

    return jax.tree_util.tree_map_with_path(leaf, params)


def preset_mask(params: Params, preset: str) -> Mask:
    """The freeze mask of a preset or freeze-ratio variant (see ``variant``)."""
    v = variant(preset)
    return layer_mask(params, v.frozen, v.ratio)


def frozen_fraction(mask: Mask) -> float:
    """The frozen share of the transferable parameters (actor L1 and L2, weights and biases)."""
    names = set(HIDDEN_LAYERS.values())
    frozen = total = 0
    for path, m in jax.tree_util.tree_leaves_with_path(mask):
        parts = _path_names(path)
        if len(parts) >= 2 and parts[0] == "actor" and parts[1] in names:
            frozen, total = frozen + int(jnp.sum(m)), total + m.size
    return frozen / total if total else 0.0


def count_frozen(mask: Mask) -> int:
    return int(sum(jnp.sum(m) for m in jax.tree.leaves(mask)))


def masked(inner: Optimizer, frozen: Mask) -> Optimizer:
    """Wrap ``inner`` so that frozen leaves never move and keep their optimizer state.

    ``frozen`` may be a traced value (the wrapper is built inside the jitted program), so one
    compiled program serves every mask.
    """
    mask_def = jax.tree.structure(frozen)

    def is_params_shaped(x) -> bool:
        return not isinstance(x, jax.Array) and jax.tree.structure(x) == mask_def

    def keep_frozen_state(new_state, old_state):
        def pick(new, old):
            if is_params_shaped(new):
                return jax.tree.map(lambda m, n, o: jnp.where(m, o, n), frozen, new, old)
            return new

        return jax.tree.map(pick, new_state, old_state, is_leaf=is_params_shaped)

    def update(grads, state, params=None):
        grads = jax.tree.map(lambda m, g: jnp.where(m, jnp.zeros_like(g), g), frozen, grads)
        direction, new_state = inner.update(grads, state, params)
        direction = jax.tree.map(lambda m, d: jnp.where(m, jnp.zeros_like(d), d), frozen, direction)
        return direction, keep_frozen_state(new_state, state)

    return Optimizer(inner.init, update)


def transfer(source_params: Params, target_params: Params, enabled: bool | jax.Array = True) -> Params:
    """PTRL transfer: copy the source actor's hidden layers L1 and L2 into the target.

    The target's input layer, output layer, log-std and the whole critic keep their fresh
    initialisation, since observation and action sizes differ between robots. ``enabled`` may
    be a traced bool so that the scratch baseline shares the program with the transfer variants.
    """
    out = jax.tree.map(lambda x: x, target_params)
    actor = dict(out["actor"])
    for name in HIDDEN_LAYERS.values():
        src, dst = source_params["actor"][name], target_params["actor"][name]
        for leaf in ("w", "b"):
            if src[leaf].shape != dst[leaf].shape:
                raise ValueError(
                    f"cannot transfer actor/{name}/{leaf}: source shape {src[leaf].shape} "
                    f"!= target shape {dst[leaf].shape} (hidden sizes must match)"
                )
        actor[name] = jax.tree.map(lambda s, d: jnp.where(enabled, s, d), src, dst)
    out["actor"] = actor
    return out

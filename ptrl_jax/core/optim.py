"""A small optimizer library in the optax style, written by hand (the design forbids optax).

An ``Optimizer`` is an ``(init, update)`` pair. ``update(grads, state, params)`` returns the
*direction* to move in and a new state; the learning rate is applied by the caller
(``apply_updates``), because PPO's adaptive-KL rule changes it every minibatch and it lives in
the train state, not in the optimizer.

Adam (Kingma & Ba, 2015), with bias correction and eps outside the square root like optax, and
t counted per parameter entry (``AdamState.count``):

    m_t = b1 m_{t-1} + (1 - b1) g          v_t = b2 v_{t-1} + (1 - b2) g^2
    m^  = m_t / (1 - b1^t)                 v^  = v_t / (1 - b2^t)
    direction = m^ / (sqrt(v^) + eps)      params <- params - lr * direction
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from ptrl_jax.core.types import Params

OptState = Any
Updates = Any


class Optimizer(NamedTuple):
    init: Callable[[Params], OptState]
    update: Callable[[Updates, OptState, Params], tuple[Updates, OptState]]


class AdamState(NamedTuple):
    count: Params
    """Steps taken, per parameter entry (shaped like the params, int32). One count per entry
    rather than one for the whole tree: ``freeze.masked`` keeps a frozen entry's state, count
    included, so an entry that starts learning late (after a critic warm-up, say) starts its bias
    correction at step 1. With a shared count its first steps would be corrected as if its zero
    moments had been averaged for the whole wait: 2 to 6 times too large."""
    mu: Params
    nu: Params


class EmptyState(NamedTuple):
    pass


def scale_by_adam(b1: float = 0.9, b2: float = 0.999, eps: float = 1e-8) -> Optimizer:
    def init(params: Params) -> AdamState:
        zeros = jax.tree.map(jnp.zeros_like, params)
        return AdamState(count=jax.tree.map(lambda p: jnp.zeros(jnp.shape(p), jnp.int32), params),
                         mu=zeros, nu=jax.tree.map(jnp.zeros_like, params))

    def update(grads: Updates, state: AdamState, params: Params | None = None):
        del params
        count = jax.tree.map(lambda c: c + 1, state.count)
        mu = jax.tree.map(lambda m, g: b1 * m + (1.0 - b1) * g, state.mu, grads)
        nu = jax.tree.map(lambda v, g: b2 * v + (1.0 - b2) * g * g, state.nu, grads)

        def direction(m, v, c):
            t = c.astype(jnp.float32)
            return (m / (1.0 - b1**t)) / (jnp.sqrt(v / (1.0 - b2**t)) + eps)

        return jax.tree.map(direction, mu, nu, count), AdamState(count=count, mu=mu, nu=nu)

    return Optimizer(init, update)


def global_norm(tree: Any) -> jax.Array:
    return jnp.sqrt(sum(jnp.sum(jnp.square(x)) for x in jax.tree.leaves(tree)))


def clip_by_global_norm(max_norm: float | jax.Array) -> Optimizer:
    """Rescale the whole gradient so that its global L2 norm is at most ``max_norm``."""

    def init(params: Params) -> EmptyState:
        del params
        return EmptyState()

    def update(grads: Updates, state: EmptyState, params: Params | None = None):
        del params
        norm = global_norm(grads)
        scale = jnp.minimum(1.0, max_norm / jnp.maximum(norm, 1e-12))
        return jax.tree.map(lambda g: g * scale, grads), state

    return Optimizer(init, update)


def chain(*optimizers: Optimizer) -> Optimizer:
    def init(params: Params) -> tuple:
        return tuple(opt.init(params) for opt in optimizers)

    def update(grads: Updates, state: tuple, params: Params | None = None):
        new_state = []
        for opt, s in zip(optimizers, state):
            grads, s = opt.update(grads, s, params)
            new_state.append(s)
        return grads, tuple(new_state)

    return Optimizer(init, update)


def apply_updates(params: Params, direction: Updates, learning_rate: jax.Array) -> Params:
    return jax.tree.map(lambda p, d: p - learning_rate * d, params, direction)


def adaptive_kl_learning_rate(
    learning_rate: jax.Array,
    kl: jax.Array,
    desired_kl: float | jax.Array,
    min_lr: float | jax.Array = 1e-5,
    max_lr: float | jax.Array = 1e-2,
    factor: float = 1.5,
) -> jax.Array:
    """rsl_rl / legged_gym's schedule: lr / 1.5 when KL > 2 target, lr * 1.5 when
    0 < KL < target / 2, kept within [min_lr, max_lr]."""
    lr = jnp.where(
        kl > 2.0 * desired_kl,
        learning_rate / factor,
        jnp.where((kl < 0.5 * desired_kl) & (kl > 0.0), learning_rate * factor, learning_rate),
    )
    return jnp.clip(lr, min_lr, max_lr)

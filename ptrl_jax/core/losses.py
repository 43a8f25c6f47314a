"""GAE and the PPO loss, as pure functions.

GAE with truncation kept apart from termination. For a step t with reward r_t, value
V(s_t) and the true next state s'_t (before any auto-reset):

    delta_t = r_t + gamma (1 - term_t) V(s'_t) - V(s_t)
    A_t     = delta_t + gamma lambda (1 - done_t) A_{t+1},   done_t = term_t or trunc_t

A fall (termination) does not bootstrap; a time-out (truncation) bootstraps from V(s'_t) but
stops the recursion, because s_{t+1} in the buffer already belongs to the next episode.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ptrl_jax.core import distributions


def compute_gae(
    rewards: jax.Array,
    values: jax.Array,
    next_values: jax.Array,
    termination: jax.Array,
    truncation: jax.Array,
    gamma: float | jax.Array,
    gae_lambda: float | jax.Array,
) -> tuple[jax.Array, jax.Array]:
    """Advantages and value targets for arrays shaped ``[time, ...]``.

    ``next_values[t]`` is V of the state reached at step t (before auto-reset).
    Returns ``(advantages, returns)`` with ``returns = advantages + values``.
    """
    deltas = rewards + gamma * (1.0 - termination) * next_values - values
    done = jnp.maximum(termination, truncation)

    def backward(carry, xs):
        delta, d = xs
        advantage = delta + gamma * gae_lambda * (1.0 - d) * carry
        return advantage, advantage

    _, advantages = jax.lax.scan(
        backward, jnp.zeros_like(values[0]), (deltas, done), reverse=True
    )
    return advantages, advantages + values


class LossInputs(NamedTuple):
    """What the PPO loss needs of a minibatch, beyond the current network outputs."""

    action: jax.Array
    old_log_prob: jax.Array
    old_value: jax.Array
    advantage: jax.Array
    target_return: jax.Array


class LossTerms(NamedTuple):
    total: jax.Array
    policy: jax.Array
    value: jax.Array
    entropy: jax.Array
    clip_fraction: jax.Array


def ppo_loss(
    mean: jax.Array,
    std: jax.Array,
    value: jax.Array,
    batch: LossInputs,
    clip_epsilon: float | jax.Array,
    value_coef: float | jax.Array,
    entropy_coef: float | jax.Array,
    clip_value: bool | jax.Array = True,
) -> LossTerms:
    """rsl_rl's PPO objective (to be minimised):

        ratio   = exp(log pi(a|s) - log pi_old(a|s))
        L_pi    = mean( max(-A ratio, -A clip(ratio, 1-eps, 1+eps)) )
        L_V     = mean( max((V - R)^2, (V_old + clip(V - V_old, -eps, eps) - R)^2) )
        L       = L_pi + c_V L_V - c_H mean(H)

    ``clip_value`` False drops L_V's clipped term; a traced bool picks per call (the critic
    warm-up fits the value unclipped).
    """
    log_prob = distributions.log_prob(batch.action, mean, std)
    ratio = jnp.exp(log_prob - batch.old_log_prob)
    surrogate = -batch.advantage * ratio
    surrogate_clipped = -batch.advantage * jnp.clip(ratio, 1.0 - clip_epsilon, 1.0 + clip_epsilon)
    policy_loss = jnp.mean(jnp.maximum(surrogate, surrogate_clipped))

    value_error = (value - batch.target_return) ** 2
    if clip_value is not False:
        clipped = batch.old_value + jnp.clip(value - batch.old_value, -clip_epsilon, clip_epsilon)
        clipped_error = jnp.maximum(value_error, (clipped - batch.target_return) ** 2)
        value_error = clipped_error if clip_value is True else jnp.where(clip_value, clipped_error, value_error)
    value_loss = jnp.mean(value_error)

    entropy = jnp.mean(distributions.entropy(std))
    total = policy_loss + value_coef * value_loss - entropy_coef * entropy
    clip_fraction = jnp.mean((jnp.abs(ratio - 1.0) > clip_epsilon).astype(jnp.float32))
    return LossTerms(total, policy_loss, value_loss, entropy, clip_fraction)

"""Running observation normalisation with pure update/normalise functions.

Statistics are merged with Chan et al.'s parallel algorithm, so a whole batch updates the
state in one step and the result equals the sequential Welford update:

    n = n_a + n_b,  delta = mean_b - mean_a
    mean = mean_a + delta n_b / n
    M2   = M2_a + M2_b + delta^2 n_a n_b / n
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp


class RunningStats(NamedTuple):
    mean: jax.Array
    m2: jax.Array
    """Sum of squared deviations from the mean; var = m2 / count."""
    count: jax.Array


def init(size: int) -> RunningStats:
    return RunningStats(
        mean=jnp.zeros((size,), jnp.float32),
        m2=jnp.zeros((size,), jnp.float32),
        count=jnp.zeros((), jnp.float32),
    )


def update(stats: RunningStats, batch: jax.Array, weights: jax.Array | None = None) -> RunningStats:
    """Merge a batch ``[..., size]`` into the statistics. Non-finite rows are skipped
    (weight 0) so one exploding simulation cannot poison the normaliser."""
    x = batch.reshape(-1, batch.shape[-1])
    w = jnp.all(jnp.isfinite(x), axis=-1).astype(jnp.float32)
    if weights is not None:
        w = w * weights.reshape(-1)
    x = jnp.where(w[:, None] > 0, x, 0.0)
    n_b = jnp.sum(w)
    safe_n_b = jnp.maximum(n_b, 1.0)
    mean_b = jnp.sum(x * w[:, None], axis=0) / safe_n_b
    m2_b = jnp.sum(w[:, None] * (x - mean_b) ** 2, axis=0)
    n = stats.count + n_b
    safe_n = jnp.maximum(n, 1.0)
    delta = mean_b - stats.mean
    mean = stats.mean + delta * n_b / safe_n
    m2 = stats.m2 + m2_b + delta**2 * stats.count * n_b / safe_n
    return RunningStats(mean=mean, m2=m2, count=n)


def variance(stats: RunningStats) -> jax.Array:
    return jnp.where(stats.count > 1, stats.m2 / jnp.maximum(stats.count, 1.0), 1.0)


def normalize(stats: RunningStats, x: jax.Array, clip: float = 10.0, eps: float = 1e-8) -> jax.Array:
    z = (x - stats.mean) / jnp.sqrt(variance(stats) + eps)
    return jnp.clip(z, -clip, clip)

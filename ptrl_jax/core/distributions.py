"""Diagonal Gaussian policy distribution as pure functions.

Actions are unsquashed, as in rsl_rl: the environment clips them. With mean mu and standard
deviation sigma per action dimension,

    log p(a) = sum_i [ -(a_i - mu_i)^2 / (2 sigma_i^2) - log sigma_i - log(2 pi) / 2 ]
    H        = sum_i [ log sigma_i + (1 + log(2 pi)) / 2 ]
    KL(old || new) = sum_i [ log(s_new/s_old) + (s_old^2 + (mu_old - mu_new)^2) / (2 s_new^2) - 1/2 ]
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

_LOG_2PI = jnp.log(2.0 * jnp.pi)


def sample(key: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    return mean + std * jax.random.normal(key, mean.shape, mean.dtype)


def log_prob(action: jax.Array, mean: jax.Array, std: jax.Array) -> jax.Array:
    z = (action - mean) / std
    return jnp.sum(-0.5 * z * z - jnp.log(std) - 0.5 * _LOG_2PI, axis=-1)


def entropy(std: jax.Array) -> jax.Array:
    return jnp.sum(jnp.log(std) + 0.5 * (1.0 + _LOG_2PI), axis=-1)


def kl_divergence(
    mean_old: jax.Array, std_old: jax.Array, mean_new: jax.Array, std_new: jax.Array
) -> jax.Array:
    return jnp.sum(
        jnp.log(std_new / std_old)
        + (std_old**2 + (mean_old - mean_new) ** 2) / (2.0 * std_new**2)
        - 0.5,
        axis=-1,
    )

"""Multilayer perceptrons as plain functions over nested-dict parameters.

Parameters are ``{"layer_0": {"w": [in, out], "b": [out]}, ..., "layer_{n}": ...}`` so every
leaf has a readable path such as ``actor/layer_1/w``; freezing and transfer address layers by
these names.
"""

from __future__ import annotations

from typing import Callable, Sequence

import jax
import jax.numpy as jnp

from ptrl_jax.core.types import Params, PRNGKey

ACTIVATIONS: dict[str, Callable[[jax.Array], jax.Array]] = {
    "elu": jax.nn.elu,
    "tanh": jnp.tanh,
    "relu": jax.nn.relu,
}


def torch_default_init(key: PRNGKey, fan_in: int, fan_out: int) -> dict[str, jax.Array]:
    """PyTorch's default ``nn.Linear`` init, which rsl_rl (and so the paper) uses.

    Both weights and biases are U(-1/sqrt(fan_in), 1/sqrt(fan_in)).
    """
    w_key, b_key = jax.random.split(key)
    bound = 1.0 / jnp.sqrt(fan_in)
    return {
        "w": jax.random.uniform(w_key, (fan_in, fan_out), jnp.float32, -bound, bound),
        "b": jax.random.uniform(b_key, (fan_out,), jnp.float32, -bound, bound),
    }


def mlp_init(key: PRNGKey, sizes: Sequence[int]) -> Params:
    """Initialise an MLP with layer sizes ``[in, hidden..., out]``."""
    if len(sizes) < 2 or any(int(s) <= 0 for s in sizes):
        raise ValueError(f"mlp sizes must be >= 2 positive ints, got {list(sizes)}")
    keys = jax.random.split(key, len(sizes) - 1)
    return {
        f"layer_{i}": torch_default_init(k, sizes[i], sizes[i + 1])
        for i, k in enumerate(keys)
    }


def mlp_apply(params: Params, x: jax.Array, activation: str = "elu") -> jax.Array:
    """Forward pass; the activation follows every layer but the last."""
    act = ACTIVATIONS[activation]
    n = len(params)
    for i in range(n):
        layer = params[f"layer_{i}"]
        x = x @ layer["w"] + layer["b"]
        if i < n - 1:
            x = act(x)
    return x

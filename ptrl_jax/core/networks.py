"""The actor-critic: two MLPs and a state-independent log standard deviation.

Parameter tree (paths are what freezing and transfer address)::

    actor/layer_0/{w,b}   obs -> 512     (input layer: robot-specific, never transferred)
    actor/layer_1/{w,b}   512 -> 256     (paper's L1)
    actor/layer_2/{w,b}   256 -> 128     (paper's L2)
    actor/layer_3/{w,b}   128 -> actions (output layer: robot-specific)
    log_std               [actions]
    critic/layer_*        privileged obs -> ... -> 1

The actor reads ``obs["state"]``; the critic reads ``obs["privileged_state"]`` (asymmetric
actor-critic, as humanoid-gym does). Observations arrive here already normalised.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from ptrl_jax.core import distributions
from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.nn import mlp_apply, mlp_init
from ptrl_jax.core.types import Observation, Params, PRNGKey


class PolicyOutput(NamedTuple):
    mean: jax.Array
    std: jax.Array


def init_actor_critic(
    key: PRNGKey, cfg: NetworkConfig, obs_size: int, privileged_obs_size: int, action_size: int
) -> Params:
    actor_key, critic_key = jax.random.split(key)
    return {
        "actor": mlp_init(actor_key, [obs_size, *cfg.actor_hidden, action_size]),
        "log_std": jnp.full((action_size,), jnp.log(cfg.init_noise_std), jnp.float32),
        "critic": mlp_init(critic_key, [privileged_obs_size, *cfg.critic_hidden, 1]),
    }


def policy_apply(params: Params, obs: Observation, cfg: NetworkConfig) -> PolicyOutput:
    mean = mlp_apply(params["actor"], obs["state"], cfg.activation)
    std = jnp.broadcast_to(jnp.exp(params["log_std"]), mean.shape)
    return PolicyOutput(mean, std)


def value_apply(params: Params, obs: Observation, cfg: NetworkConfig) -> jax.Array:
    return mlp_apply(params["critic"], obs["privileged_state"], cfg.activation)[..., 0]


def make_policy(
    params: Params, cfg: NetworkConfig, deterministic: bool = False
) -> Callable[[Observation, PRNGKey], jax.Array]:
    """A policy function ``(normalised obs, key) -> action`` in the Brax manner."""

    def policy(obs: Observation, key: PRNGKey) -> jax.Array:
        out = policy_apply(params, obs, cfg)
        if deterministic:
            return out.mean
        return distributions.sample(key, out.mean, out.std)

    return policy

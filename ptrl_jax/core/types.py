"""Type aliases and the transition pytree. No logic lives here."""

from __future__ import annotations

from typing import Any, Mapping, NamedTuple

import jax

PRNGKey = jax.Array
Params = Any  # nested dict of arrays, e.g. {"actor": {"layer_0": {"w", "b"}, ...}}
Mask = Any  # pytree shaped like Params with bool array leaves
Observation = Mapping[str, jax.Array]  # {"state": actor input, "privileged_state": critic input}
Metrics = Mapping[str, jax.Array]


class Transition(NamedTuple):
    """One environment step as seen by PPO, batched over [time, env] in a rollout."""

    observation: Observation
    action: jax.Array
    """Raw (unclipped) action sampled from the policy."""
    log_prob: jax.Array
    action_mean: jax.Array
    """Policy mean and std at sampling time: the adaptive-KL rule compares against them."""
    action_std: jax.Array
    reward: jax.Array
    termination: jax.Array
    """1.0 where the episode ended in a terminal state (fall): no bootstrap."""
    truncation: jax.Array
    """1.0 where the episode was cut by the time limit: bootstrap from the value."""
    final_observation: Observation
    """Observation reached by this step, before any auto-reset. V(final_observation) is the
    bootstrap target, so time-outs are valued correctly even though the env has already reset."""

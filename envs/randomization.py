"""Domain randomization: ground friction, added base mass, PD gain and motor strength scaling,
and random pushes (legged_gym / humanoid-gym), switchable per experiment.

Two ways in, one set of definitions:
- ``randomize(model, rng) -> (model, in_axes)``, the MuJoCo Playground interface: ``rng`` holds
  one key per environment, the returned ``mjx.Model`` is batched along axis 0 in exactly the
  fields ``in_axes`` marks with 0, and ``jax.vmap(step, in_axes=(in_axes, 0, 0))`` runs each env
  on its own model.
- ``LeggedEnv`` with ``config.randomization.enabled``: each episode draws its own sample at
  reset (``sample``) and keeps it in ``state.info["randomization"]``; ``step`` rebuilds the model
  from it (``apply``). This keeps the env's contract (``vmap(env.step)`` over plain states), so
  the trainer needs no knowledge of randomization, and it redraws on every reset, as legged_gym
  does for its gains and pushes (it draws friction and mass once per env at creation).

The PD gain scales act on the policy's PD law: Kp in the torque the env computes, Kd through
the model's joint damping (``envs.base``: the PD law's damping is implicit joint damping). Motor
strength scales the clipped stiffness torque, as legged_gym's ``motor_strength`` does.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax


@dataclass(frozen=True)
class RandomizationConfig:
    """What is randomized and how much (uniform ranges). Off unless ``enabled``."""

    enabled: bool = False
    """Master switch. Off by default: every robot can use it; experiments turn it on."""
    friction: tuple[float, float] = (0.5, 1.25)
    """Sliding friction of every geom (ground and feet alike), absolute (legged_gym
    friction_range [0.5, 1.25])."""
    added_base_mass: tuple[float, float] = (-1.0, 1.0)
    """Mass added to the base body, kg (legged_gym added_mass_range [-1, 1])."""
    kp_scale: tuple[float, float] = (0.9, 1.1)
    """Factor on every joint's Kp."""
    kd_scale: tuple[float, float] = (0.9, 1.1)
    """Factor on every joint's Kd (the model's joint damping)."""
    motor_strength: tuple[float, float] = (0.9, 1.1)
    """Factor on the applied joint torque (after the torque limit)."""
    push_interval_s: float = 8.0
    """A random push (base velocity change) every this many seconds of an episode."""
    max_push_vel: float = 0.5
    """Pushes change the base's world-frame x and y velocity by U(-v, v) each, m/s (legged_gym
    max_push_vel_xy 1.0; humanoid-gym XBot-L 0.2)."""

    def __post_init__(self):
        for name in ("friction", "added_base_mass", "kp_scale", "kd_scale", "motor_strength"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"randomization.{name}: low {lo} > high {hi}")
        for name in ("friction", "kp_scale", "kd_scale", "motor_strength"):
            if getattr(self, name)[0] < 0:
                raise ValueError(f"randomization.{name} must be >= 0, got {getattr(self, name)}")
        if self.push_interval_s <= 0 or self.max_push_vel < 0:
            raise ValueError("randomization.push_interval_s must be > 0 and max_push_vel >= 0")


def sample(cfg: RandomizationConfig, key: jax.Array) -> dict[str, jax.Array]:
    """One environment's draw: the scalars that ``apply`` and the PD law use."""
    names = ("friction", "added_base_mass", "kp_scale", "kd_scale", "motor_strength")
    keys = jax.random.split(key, len(names))
    return {
        n: jax.random.uniform(k, (), minval=getattr(cfg, n)[0], maxval=getattr(cfg, n)[1])
        for n, k in zip(names, keys)
    }


# The model fields a draw changes; everything else is shared by all environments.
RANDOMIZED_FIELDS = ("geom_friction", "body_mass", "dof_damping")


def randomized_fields(model, draw: dict[str, jax.Array], base_body: int = 1) -> dict[str, jax.Array]:
    """The fields of ``RANDOMIZED_FIELDS`` under one draw: friction, base mass and Kd (joint
    damping; the free joint's six DOFs keep theirs)."""
    return {
        "geom_friction": model.geom_friction.at[:, 0].set(draw["friction"]),
        "body_mass": model.body_mass.at[base_body].add(draw["added_base_mass"]),
        "dof_damping": model.dof_damping.at[6:].multiply(draw["kd_scale"]),
    }


def apply(model, draw: dict[str, jax.Array], base_body: int = 1):
    """The model with one draw applied."""
    return model.replace(**randomized_fields(model, draw, base_body))


def randomize(model, rng: jax.Array, cfg: RandomizationConfig = RandomizationConfig(), base_body: int = 1):
    """MuJoCo Playground's interface: ``rng`` of shape (num_envs, 2) -> (batched model, in_axes).

    The PD-law factors (kp_scale, motor_strength) are not model fields; ``LeggedEnv`` applies
    them, so this function covers friction, base mass and Kd.
    """
    if rng.ndim != 2:
        raise ValueError(f"randomize: rng must hold one key per environment, shape (n, 2); got {rng.shape}")
    fields = jax.vmap(lambda k: randomized_fields(model, sample(cfg, k), base_body))(rng)
    batched = model.replace(**fields)
    in_axes = jax.tree.map(lambda _: None, model)
    in_axes = in_axes.replace(**{f: 0 for f in RANDOMIZED_FIELDS})
    return batched, in_axes

"""Domain randomization (envs/randomization.py): the Playground-style batched model, the draws'
ranges, and that an enabled env applies its draw (friction, mass, gains, strength, pushes)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.randomization import RANDOMIZED_FIELDS, RandomizationConfig, apply, randomize


@pytest.fixture(scope="module")
def go2():
    return envs.make("go2")


class TestRandomize:
    def test_batches_exactly_the_randomized_fields(self, go2):
        model, in_axes = randomize(go2.sys, jax.random.split(jax.random.PRNGKey(0), 5))
        for name in RANDOMIZED_FIELDS:
            assert getattr(in_axes, name) == 0
            assert getattr(model, name).shape == (5, *getattr(go2.sys, name).shape)
        assert jax.tree.leaves(in_axes) == [0] * len(RANDOMIZED_FIELDS)  # every other leaf: None
        np.testing.assert_array_equal(model.geom_size, go2.sys.geom_size)  # shared, unbatched
        # vmap takes the pair as it is, one model per environment:
        total = jax.vmap(lambda m: m.body_mass.sum() + 0.0 * m.geom_size.sum(), in_axes=(in_axes,))(model)
        np.testing.assert_allclose(total, np.asarray(model.body_mass).sum(axis=1), rtol=1e-6)

    def test_draws_lie_in_their_ranges_and_touch_only_their_entries(self, go2):
        cfg = RandomizationConfig(friction=(0.2, 0.3), added_base_mass=(2.0, 3.0), kd_scale=(1.5, 2.0))
        model, _ = randomize(go2.sys, jax.random.split(jax.random.PRNGKey(1), 64), cfg)
        mu = np.asarray(model.geom_friction)
        assert np.all((mu[:, :, 0] >= 0.2) & (mu[:, :, 0] <= 0.3))
        np.testing.assert_array_equal(mu[:, :, 1:], np.broadcast_to(go2.sys.geom_friction[:, 1:], mu[:, :, 1:].shape))
        added = np.asarray(model.body_mass) - np.asarray(go2.sys.body_mass)
        base = go2._base_body  # noqa: SLF001
        assert np.all((added[:, base] >= 2.0) & (added[:, base] <= 3.0))
        assert np.all(np.delete(added, base, axis=1) == 0.0)
        ratio = np.asarray(model.dof_damping)[:, 6:] / np.asarray(go2.sys.dof_damping)[6:]
        assert np.all((ratio >= 1.5 - 1e-6) & (ratio <= 2.0 + 1e-6))
        np.testing.assert_array_equal(np.asarray(model.dof_damping)[:, :6], 0 * ratio[:, :6] + go2.sys.dof_damping[:6])
        assert np.ptp(mu[:, 0, 0]) > 0.05  # environments differ

    def test_refuses_a_single_key(self, go2):
        with pytest.raises(ValueError, match=r"one key per environment"):
            randomize(go2.sys, jax.random.PRNGKey(0))

    def test_refuses_inverted_ranges(self):
        with pytest.raises(ValueError, match=r"randomization.friction: low 2.0 > high 1.0"):
            RandomizationConfig(friction=(2.0, 1.0))


class TestEnvApplies:
    def test_gains_and_strength_scale_the_pd_torque(self, go2):
        data = jax.jit(go2.reset)(jax.random.PRNGKey(0)).pipeline_state
        target = go2._default_joints + 0.01  # noqa: SLF001 (small: stays inside the torque limit)
        nominal = go2.pd_torque(data, target)
        np.testing.assert_allclose(go2.pd_torque(data, target, 1.1, 0.5), 0.55 * nominal, rtol=1e-5)

    def test_reset_draws_per_episode_and_step_keeps_the_draw(self, go2):
        cfg = dataclasses.replace(go2.config, randomization=RandomizationConfig(enabled=True))
        env = envs.make("go2", cfg)
        states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 4))
        draws = states.info["randomization"]
        assert set(draws) == {"friction", "added_base_mass", "kp_scale", "kd_scale", "motor_strength"}
        assert np.ptp(np.asarray(draws["friction"])) > 0.0
        model = apply(env.sys, jax.tree.map(lambda x: x[0], draws), env._base_body)  # noqa: SLF001
        assert float(model.geom_friction[0, 0]) == pytest.approx(float(draws["friction"][0]))

    def test_push_changes_planar_base_velocity_only_when_due(self, go2):
        cfg = dataclasses.replace(go2.config, randomization=RandomizationConfig(enabled=True, push_interval_s=0.2))
        env = envs.make("go2", cfg)
        state = env.reset(jax.random.PRNGKey(3))
        every = int(round(0.2 / cfg.ctrl_dt))
        for step, due in ((every, True), (every + 1, False), (0, False)):
            info = {**state.info, "step": jnp.asarray(step)}
            pushed = env._push(state.pipeline_state, info)  # noqa: SLF001
            dv = np.asarray(pushed.qvel - state.pipeline_state.qvel)
            assert np.all(dv[2:] == 0.0)
            assert (np.abs(dv[:2]).max() > 0.0) == due
            assert np.abs(dv[:2]).max() <= cfg.randomization.max_push_vel

    def test_stepping_applies_the_draw(self, go2):
        """With motor strength drawn from [0, 0] no torque reaches the joints, and Go2 (which
        holds its pose without randomization: test_envs.py's registry walk) folds within 1 s.
        Friction drawn per env reaches the stepped model too (the same draw as at reset)."""
        rnd = RandomizationConfig(enabled=True, motor_strength=(0.0, 0.0), push_interval_s=100.0)
        env = envs.make("go2", dataclasses.replace(go2.config, randomization=rnd))
        steps = int(round(1.0 / env.config.ctrl_dt))

        @jax.jit
        def fold(keys):
            state = jax.vmap(env.reset)(keys)

            def step(s, _):
                s = jax.vmap(env.step)(s, jnp.zeros((keys.shape[0], env.action_size)))
                return s, (s.pipeline_state.qpos[:, 2], s.info["termination"])

            return jax.lax.scan(step, state, None, length=steps)[1]

        heights, fell = map(np.asarray, fold(jax.random.split(jax.random.PRNGKey(0), 2)))
        stand = float(go2.mj_model.key("home").qpos[2])
        # A fall ends the episode (and resets the height), so either sign counts, per env.
        assert np.all((heights.min(axis=0) < 0.6 * stand) | fell.any(axis=0)), (heights.min(axis=0), fell.any(axis=0))

"""Both robots reset and step under jit without NaN, with the stated sizes; auto-reset and
truncation bookkeeping behave."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs


def rollout(env, n_envs=8, steps=10, seed=0, action_scale=0.3):
    reset = jax.jit(jax.vmap(env.reset))
    step = jax.jit(jax.vmap(env.step))
    state = reset(jax.random.split(jax.random.PRNGKey(seed), n_envs))
    states = [state]
    key = jax.random.PRNGKey(seed + 1)
    for _ in range(steps):
        key, k = jax.random.split(key)
        state = step(state, action_scale * jax.random.normal(k, (n_envs, env.action_size)))
        states.append(state)
    return states


@pytest.mark.parametrize("robot,obs,priv,act", [("go2", 45, 53, 12), ("xbot_l", 47 * 15, 67, 12)])
class TestEnvContract:
    def test_sizes_and_finite(self, robot, obs, priv, act):
        env = envs.make(robot)
        states = rollout(env)
        assert env.action_size == act
        for s in states:
            assert s.obs["state"].shape == (8, obs)
            assert s.obs["privileged_state"].shape == (8, priv)
            for leaf in jax.tree.leaves((s.obs, s.reward, s.metrics)):
                assert np.all(np.isfinite(np.asarray(leaf)))
        # Every reward term is logged, and the state type is stable across steps (no recompiles).
        assert set(states[-1].metrics) == {f"reward/{k}" for k in dataclasses.asdict(env.config.rewards)}
        assert jax.tree.map(lambda a, b: (a.shape, a.dtype, a.weak_type) == (b.shape, b.dtype, b.weak_type),
                            states[0], states[-1]) == jax.tree.map(lambda a: True, states[0])


class TestGo2Observation:
    def test_table1_layout_at_default_pose(self, go2_env):
        cfg = dataclasses.replace(go2_env.config, init_joint_noise=0.0, init_base_vel_noise=0.0)
        env = envs.make("go2", cfg)
        s = jax.jit(env.reset)(jax.random.PRNGKey(0))
        o = np.asarray(s.obs["state"])
        np.testing.assert_allclose(o[0:3], 0.0, atol=1e-6)  # angular velocity
        np.testing.assert_allclose(o[3:6], [0, 0, -1], atol=1e-6)  # projected gravity
        np.testing.assert_allclose(o[6:18], 0.0, atol=1e-6)  # joint pos - default
        np.testing.assert_allclose(o[18:30], 0.0, atol=1e-6)  # joint vel
        np.testing.assert_allclose(o[30:33], np.asarray(s.info["command"]) * [2, 2, 0.25], atol=1e-6)
        np.testing.assert_allclose(o[33:45], 0.0)  # last action

    def test_pd_gains_and_torque_limits(self, go2_env):
        assert np.allclose(go2_env._kp, 40.0) and np.allclose(go2_env._kd, 0.5)
        np.testing.assert_allclose(go2_env.mj_model.dof_damping[6:], 0.5)  # Kd is implicit joint damping
        s = jax.jit(go2_env.reset)(jax.random.PRNGKey(0))
        tau = go2_env.pd_torque(s.pipeline_state, go2_env._default_joints + 10.0)
        np.testing.assert_allclose(np.asarray(tau), np.asarray(go2_env._torque_limit))


class TestAutoReset:
    def test_time_out_is_truncation_not_termination(self, go2_env):
        cfg = dataclasses.replace(go2_env.config, episode_length_s=3 * go2_env.config.ctrl_dt)
        env = envs.make("go2", cfg)
        states = rollout(env, n_envs=4, steps=3, action_scale=0.0)
        last = states[-1]
        assert np.all(np.asarray(last.done) == 1)
        assert np.all(np.asarray(last.info["truncation"]) == 1)
        assert np.all(np.asarray(last.info["termination"]) == 0)
        assert np.all(np.asarray(last.info["step"]) == 0)  # reset happened
        # final_obs is the pre-reset observation, obs the fresh one
        assert not np.allclose(last.info["final_obs"]["state"], last.obs["state"])

    def test_non_finite_physics_ends_the_episode_with_zero_reward(self, go2_env):
        s = jax.jit(go2_env.reset)(jax.random.PRNGKey(0))
        bad = s.replace(pipeline_state=s.pipeline_state.replace(qvel=s.pipeline_state.qvel.at[0].set(jnp.nan)))
        out = jax.jit(go2_env.step)(bad, jnp.zeros(12))
        assert float(out.info["nonfinite"]) == 1 and float(out.info["termination"]) == 1
        assert float(out.reward) == 0.0
        assert np.all(np.isfinite(out.obs["state"])) and np.all(np.isfinite(out.pipeline_state.qpos))


class TestRegistry:
    def test_unknown_robot_suggests(self):
        with pytest.raises(ValueError, match="did you mean 'go2'"):
            envs.make("go3")

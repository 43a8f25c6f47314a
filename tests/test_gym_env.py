"""The Gymnasium view on MuJoCo C: API conformance, rendering, and agreement with the MJX env."""

import dataclasses

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State
from gymnasium.utils.env_checker import check_env
from mujoco import mjx

import envs


@pytest.mark.parametrize("robot", envs.robot_names())
class TestGymnasiumApi:
    def test_check_env_passes(self, robot):
        env = gymnasium.make(envs.GYM_IDS[robot])
        check_env(env.unwrapped, skip_render_check=True)
        assert env.spec is not None and env.spec.id == envs.GYM_IDS[robot]

    def test_render_rgb_array(self, robot):
        env = envs.LocomotionGymEnv(robot, render_mode="rgb_array", width=64, height=48)
        env.reset(seed=0)
        frame = env.render()
        env.close()
        assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8
        assert frame.std() > 1.0  # the robot and the floor, not a blank image


class TestVectorEnv:
    def test_sync_vector_env_steps(self):
        vec = gymnasium.make_vec(envs.GYM_IDS["go2"], num_envs=2, vectorization_mode="sync")
        obs, _ = vec.reset(seed=0)
        assert obs.shape == (2, 45) and obs.dtype == np.float32
        obs, reward, terminated, truncated, _ = vec.step(np.zeros((2, 12), np.float32))
        assert obs.shape == (2, 45) and reward.shape == (2,) and not terminated.any()
        vec.close()


class TestFixedCommand:
    def test_reset_option_holds_the_command(self):
        env = envs.LocomotionGymEnv("go2")
        obs, info = env.reset(seed=1, options={"command": (0.5, 0.0, 0.25)})
        for _ in range(3):
            obs, *_, info = env.step(np.zeros(12, np.float32))
        np.testing.assert_allclose(info["command"], [0.5, 0.0, 0.25])
        # Table I: the command sits at obs[30:33], scaled by (2, 2, 0.25).
        np.testing.assert_allclose(obs[30:33], [1.0, 0.0, 0.0625], atol=1e-6)

    def test_bad_action_shape_is_refused(self):
        env = envs.LocomotionGymEnv("go2")
        env.reset(seed=0)
        with pytest.raises(ValueError, match="expects"):
            env.step(np.zeros(3, np.float32))


class TestCommandCurriculum:
    """The view carries its curriculum level across episodes, as an env of the trainer does."""

    def env(self):
        cfg = envs.default_config("go2")
        cfg = dataclasses.replace(cfg, commands=dataclasses.replace(cfg.commands, curriculum=True))
        return envs.LocomotionGymEnv("go2", cfg)

    def end_episode(self, env, tracking, terminated, truncated):
        """As if the episode had ended after 100 steps with a mean tracking kernel ``tracking``."""
        env._info = {**env._info, "step": jnp.asarray(100, jnp.int32), "tracking_sum": jnp.asarray(100.0 * tracking)}
        env._ended = (terminated, truncated)

    def test_the_level_moves_at_each_episode_end_and_stays_mid_episode(self):
        env = self.env()
        _, info = env.reset(seed=0)
        assert info["command_level"] == pytest.approx(0.3)  # curriculum_start
        self.end_episode(env, 0.9, False, True)  # a time-out that tracked: up one step
        _, info = env.reset(seed=1)
        assert info["command_level"] == pytest.approx(0.4)
        self.end_episode(env, 0.5, False, True)  # a time-out below the bar: stays
        assert env.reset(seed=2)[1]["command_level"] == pytest.approx(0.4)
        self.end_episode(env, 0.9, True, False)  # a fall: down one step
        assert env.reset(seed=3)[1]["command_level"] == pytest.approx(0.3)
        env.reset(options={"command_level": 0.7})
        env.step(np.zeros(12, np.float32))
        assert env.reset(seed=4)[1]["command_level"] == pytest.approx(0.7)  # reset mid-episode: kept

    def test_a_bad_level_is_refused(self):
        with pytest.raises(ValueError, match=r"must lie in \[curriculum_start=0.3, 1\], got 1.5"):
            self.env().reset(options={"command_level": 1.5})
        with pytest.raises(ValueError, match="needs commands.curriculum=true"):
            envs.LocomotionGymEnv("go2").reset(options={"command_level": 0.5})


def state_like(gym_env, env=None):
    """A state of the JAX env ``env`` (default: the Gymnasium view's own MJX env) holding exactly
    the MuJoCo C env's current state. Both engines keep their physics in an ``mjx.Data``."""
    e = env or gym_env.mjx_env
    data = mjx.make_data(e.sys).replace(
        qpos=jnp.asarray(gym_env.data.qpos, jnp.float32), qvel=jnp.asarray(gym_env.data.qvel, jnp.float32)
    )
    data = mjx.kinematics(e.sys, data)
    obs, info = e._observe(data, dict(gym_env._info))
    info["final_obs"] = obs
    return State(data, obs, jnp.zeros(()), jnp.zeros(()), {}, info)


# The Gymnasium view (numpy, MuJoCo C, float64) against the trainer's JAX env stepped by the same
# open-loop actions. Go2 against engine=mujoco (MuJoCo C too, stepped through the host callback
# from float32 states): the view's observation and reward code against the trainer's, at the cost
# of a MuJoCo C compile. MJX against MuJoCo C is tests/test_envs.py::TestEngines, for every robot.
# XBot-L against MJX, marked slow (a single-env MJX step costs about a minute to compile; `pytest
# -m slow` runs it): the view against MJX directly, on its corner-sphere soles.
@pytest.mark.parametrize("robot,engine", [("go2", "mujoco"), pytest.param("xbot_l", "mjx", marks=pytest.mark.slow)])
@pytest.mark.xdist_group("sim_to_sim")  # scheduled early with the other one-compile groups (conftest)
class TestSimToSimAgreement:
    """The Gymnasium view and the JAX env step the same model with the same solver settings.
    Over the first 10 control steps of an open-loop action sequence they agree within these
    tolerances (rad or m for qpos; per-step, dt-weighted reward).

    XBot-L once needed 5e-2 against MJX: on its box soles MJX kept only the corners within 1 mm
    of the deepest one (``plane_convex``), 2 contacts where MuJoCo C had 5, and the states parted
    by 3.7e-2 in ten steps. Its soles are corner spheres since stop 57, one contact per sphere in
    both engines, and it is held to Go2's bound."""

    QPOS_TOL = 2e-3
    REWARD_TOL = 2e-3

    def test_first_steps_agree(self, robot, engine):
        gym_env = envs.LocomotionGymEnv(robot)
        gym_env.reset(seed=3, options={"command": (0.5, 0.0, 0.0)})
        env = gym_env.mjx_env if engine == "mjx" else envs.make(robot, dataclasses.replace(gym_env.config, engine=engine))
        state = state_like(gym_env, env)
        step = jax.jit(env.step)
        n = gym_env.action_space.shape[0]
        for t in range(10):
            action = (0.5 * np.sin(0.3 * t + np.arange(n))).astype(np.float32)
            _, reward_c, terminated, _, _ = gym_env.step(action)
            state = step(state, jnp.asarray(action))
            assert not terminated and float(state.done) == 0.0
            np.testing.assert_allclose(np.asarray(state.pipeline_state.qpos), gym_env.data.qpos,
                                       atol=self.QPOS_TOL)
            assert abs(float(state.reward) - reward_c) < self.REWARD_TOL

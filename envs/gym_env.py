"""A Gymnasium view of every robot on MuJoCo C (not MJX): one env, numpy in and out.

    import envs, gymnasium
    env = gymnasium.make("ptrl/Go2-v0", render_mode="rgb_array")
    vec = gymnasium.make_vec("ptrl/Go2-v0", num_envs=4, vectorization_mode="sync")

Same model file, same physics settings (time step, solver iterations, implicit PD damping) and
the *same* observation, reward, termination and command code as the MJX env: after each
``mujoco.mj_step`` the MJX env's own ``evaluate_transition`` runs (jitted, on the CPU) on a small
view of ``MjData``. Only the physics engine differs, which is the point of a sim-to-sim check.

- ``observation``: the actor's observation (``obs["state"]``), float32.
- ``action``: the policy's raw action; joint targets are ``default + action_scale * action``.
- ``reward``: the MJX env's reward; ``info`` holds each weighted term, the command and the
  critic's ``privileged_state``.
- ``terminated``: a fall (or non-finite physics); ``truncated``: the episode time limit.
- ``reset(options={"command": (vx, vy, yaw_rate)})`` holds a fixed command for the episode.
- With ``commands.curriculum``, the view keeps its command level across episodes as each env of
  the trainer does: a reset after a time-out or a fall moves it by the env's own rule
  (``next_command_level``), a reset mid-episode keeps it, and ``options={"command_level": x}``
  sets it. ``info["command_level"]`` reports it.
"""

from __future__ import annotations

import os
from typing import Any, NamedTuple

os.environ.setdefault("MUJOCO_GL", "egl")  # headless offscreen rendering (see envs/__init__)

import gymnasium  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from gymnasium import spaces  # noqa: E402

GYM_IDS = {
    "go2": "ptrl/Go2-v0", "a1": "ptrl/A1-v0", "anymal_b": "ptrl/ANYmalB-v0", "anymal_c": "ptrl/ANYmalC-v0",
    "xbot_l": "ptrl/XBotL-v0", "mit_humanoid": "ptrl/MITHumanoid-v0", "cassie": "ptrl/Cassie-v0",
    "tron1": "ptrl/TRON1-v0",
}
"""Registered Gymnasium ids per robot (``ptrl/<Name>-v0``)."""


class DataView(NamedTuple):
    """The fields of ``MjData`` the env's observation and reward code reads, as float32."""

    qpos: jax.Array
    qvel: jax.Array
    xpos: jax.Array
    site_xpos: jax.Array

    @classmethod
    def of(cls, data: mujoco.MjData) -> "DataView":
        f = lambda x: np.asarray(x, np.float32)  # noqa: E731
        return cls(f(data.qpos), f(data.qvel), f(data.xpos), f(data.site_xpos))


class LocomotionGymEnv(gymnasium.Env):
    """One robot on MuJoCo C with the MJX env's observation, action and reward definitions."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, robot: str = "go2", config: Any = None, render_mode: str | None = None,
                 width: int = 480, height: int = 360):
        from envs.registry import make  # late import: registry -> families -> base

        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode={render_mode!r}: only 'rgb_array' is supported")
        self.robot = robot
        self.mjx_env = make(robot, config)
        self.config = self.mjx_env.config
        self.model = self.mjx_env.mj_model
        self.data = mujoco.MjData(self.model)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.config.ctrl_dt))}
        self._size = (height, width)
        self._renderer: mujoco.Renderer | None = None

        env = self.mjx_env
        self._initial = jax.jit(env._initial_qpos_qvel)  # noqa: SLF001 (same package)
        self._first_obs = jax.jit(self._first_observation)
        self._transition = jax.jit(env.evaluate_transition)
        self._default_joints = np.asarray(env._default_joints, np.float64)  # noqa: SLF001
        self._kp = np.asarray(env._kp, np.float64)  # noqa: SLF001
        self._torque_limit = np.asarray(env._torque_limit, np.float64)  # noqa: SLF001

        obs_size = int(jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs["state"].shape[-1])
        self.observation_space = spaces.Box(-np.inf, np.inf, (obs_size,), np.float32)
        clip = float(self.config.clip_actions)
        self.action_space = spaces.Box(-clip, clip, (env.action_size,), np.float32)
        self._info: dict | None = None
        self._fixed_command: np.ndarray | None = None
        self._ended = (False, False)  # (terminated, truncated) of the last step
        self._next_level = jax.jit(env.next_command_level)
        self._tracked = env.tracked
        self._steps = env.curriculum_steps

    def _first_observation(self, view: DataView, key: jax.Array, command, use_command, level):
        info = self.mjx_env._fresh_info(view, key, level)  # noqa: SLF001
        info["command"] = jnp.where(use_command, command, info["command"])
        obs, info = self.mjx_env._observe(view, info)  # noqa: SLF001
        return obs, info

    def _command_args(self):
        use = self._fixed_command is not None
        cmd = self._fixed_command if use else np.zeros(3, np.float32)
        return jnp.asarray(cmd, jnp.float32), jnp.asarray(use)

    # ----- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        command = options.get("command")
        if command is not None:
            command = np.asarray(command, np.float32)
            if command.shape != (3,):
                raise ValueError(f"options['command'] must be (vx, vy, yaw_rate), got shape {command.shape}")
        level = self._command_level(options.get("command_level"))
        self._fixed_command = command
        key = jax.random.PRNGKey(int(self.np_random.integers(0, 2**31 - 1)))
        k_init, k_info = jax.random.split(key)
        qpos, qvel = jax.device_get(self._initial(k_init))
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = qpos
        self.data.qvel[:] = qvel
        mujoco.mj_forward(self.model, self.data)
        obs, self._info = self._first_obs(DataView.of(self.data), k_info, *self._command_args(), level)
        self._ended = (False, False)
        return self._observation(obs), self._info_dict(obs, {})

    def _command_level(self, requested) -> jax.Array:
        """The next episode's curriculum level: ``requested`` if given, else the last episode's
        moved by the curriculum's rule where it ended (kept where it was reset mid-episode), else
        ``curriculum_start``."""
        c = self.config.commands
        if requested is not None:
            if not c.curriculum:
                raise ValueError("options['command_level'] needs commands.curriculum=true in the env config")
            if not c.curriculum_start <= float(requested) <= 1.0:
                raise ValueError(f"options['command_level'] must lie in [curriculum_start={c.curriculum_start}, 1], "
                                 f"got {requested}")
            return jnp.asarray(float(requested), jnp.float32)
        if not c.curriculum or self._info is None:
            return jnp.asarray(c.curriculum_start, jnp.float32)
        info = self._info
        fell, timed_out = self._ended
        if not (fell or timed_out):
            return jnp.asarray(info["command_level"], jnp.float32)
        return self._next_level(info["command_level"], self._tracked(info, self._steps(info["step"])),
                                jnp.asarray(fell), jnp.asarray(timed_out))

    def step(self, action):
        if self._info is None:
            raise RuntimeError("call reset() before step()")
        action = np.asarray(action, np.float32)
        if action.shape != self.action_space.shape:
            raise ValueError(f"action has shape {action.shape}; {self.robot} expects {self.action_space.shape}")
        clip = self.config.clip_actions
        target = self._default_joints + self.config.action_scale * np.clip(action, -clip, clip)
        for _ in range(self.config.decimation):
            # The stiffness half of the PD law; the -Kd qdot half is the model's joint damping,
            # integrated implicitly by MuJoCo exactly as in the MJX env.
            tau = self._kp * (target - self.data.qpos[7:])
            self.data.ctrl[:] = np.clip(tau, -self._torque_limit, self._torque_limit)
            mujoco.mj_step(self.model, self.data)
        t = self._transition(DataView.of(self.data), jnp.asarray(action), self._info)
        info = t.info
        if self._fixed_command is not None:
            info = {**info, "command": jnp.asarray(self._fixed_command)}
        self._info = info
        self._ended = (bool(t.termination), bool(t.truncation))
        return (
            self._observation(t.obs),
            float(t.reward),
            bool(t.termination),
            bool(t.truncation),
            self._info_dict(t.obs, t.metrics),
        )

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, *self._size)
        self._renderer.update_scene(self.data, camera=self._camera())
        return self._renderer.render()

    def close(self):
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # ----- helpers ------------------------------------------------------------------------------
    def _camera(self) -> mujoco.MjvCamera:
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
        cam.trackbodyid = 1
        cam.distance = 3.0 * max(float(self.model.stat.extent), 0.5)
        cam.azimuth, cam.elevation = 135.0, -20.0
        return cam

    @staticmethod
    def _observation(obs) -> np.ndarray:
        return np.asarray(obs["state"], np.float32)

    def _info_dict(self, obs, metrics) -> dict[str, Any]:
        info = {
            "privileged_state": np.asarray(obs["privileged_state"], np.float32),
            "command": np.asarray(self._info["command"], np.float32),
        }
        if self.config.commands.curriculum:
            info["command_level"] = float(self._info["command_level"])
        info.update({k: float(v) for k, v in metrics.items()})
        return info


def register() -> None:
    """Register ``ptrl/<Name>-v0`` for every robot of the registry (idempotent)."""
    from envs.registry import ROBOTS

    for robot in ROBOTS:
        env_id = GYM_IDS.get(robot) or f"ptrl/{robot.title().replace('_', '')}-v0"
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="envs.gym_env:LocomotionGymEnv",
                kwargs={"robot": robot},
                max_episode_steps=None,
                disable_env_checker=False,
            )

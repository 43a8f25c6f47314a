"""The locomotion base environment: a Brax ``PipelineEnv`` on the MJX backend.

What every legged robot here shares:
- PD joint control at the physics rate. The policy's action a sets a joint target
  ``q* = q_default + action_scale * clip(a)``; each physics substep applies
  ``tau = clip(Kp (q* - q), -tau_max, tau_max)`` through torque motors, and the ``-Kd qdot``
  half of the PD law is the model's joint damping, which MuJoCo's Euler integrator treats
  implicitly. That keeps high-Kd, light joints (humanoid ankles) stable at a 5 ms step; the
  price is that the damping torque is not clipped with the stiffness torque.
- Velocity commands (vx, vy, yaw rate) sampled per episode and every ``resample_time_s``.
- Episode bookkeeping and a cheap auto-reset inside ``step``: truncation (time-out) is recorded
  apart from termination (fall or non-finite physics), and the observation reached *before* the
  reset is kept in ``info["final_obs"]`` so the trainer can bootstrap time-outs correctly.
  Resetting only rewrites qpos/qvel (no ``mjx.forward``): the next ``mjx.step`` recomputes
  everything else, so a reset costs almost nothing.
- Rewards are a dict of named terms; the reward is ``dt * sum_i w_i term_i`` (the legged_gym
  convention), optionally clipped at zero, and every weighted term is logged in ``metrics``.

Families (quadruped, biped) subclass this and supply observations and reward terms.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from brax import math
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf

from envs import randomization, semantics
from envs.mujoco_engine import ENGINES, MujocoStepper
from envs.randomization import RandomizationConfig

def _assets_dir() -> Path:
    """The robots' MJCF: ``envs/assets/`` in an installed wheel (pyproject.toml ships assets/
    there), else the checkout's ``assets/``."""
    packaged = Path(__file__).resolve().parent / "assets"
    return packaged if packaged.is_dir() else Path(__file__).resolve().parents[1] / "assets"


ASSETS_DIR = _assets_dir()


def asset_sha256(asset: str) -> str:
    """The first 16 hex digits of the SHA-256 of the MJCF file ``asset`` (a name in
    ``ASSETS_DIR``): which version of a robot's model a checkpoint or a resume state was trained
    on. A changed model changes a policy's physics (XBot-L's soles, stop 57) with every config and
    array shape the same.

    Once this process has loaded the file (``load_mj_model``), the digest is that of the bytes it
    loaded, so a model edited while a run trains does not stamp the run's checkpoints with the
    edit; before that it is the file's as it is now. The digest is of the raw bytes: an edit to a
    comment or to line endings counts as another version."""
    path = _asset_path(asset)
    return _LOADED_DIGESTS.get(path.resolve()) or _sha256(path.read_bytes())


_LOADED_DIGESTS: dict[Path, str] = {}
"""``asset_sha256`` of each MJCF file as ``load_mj_model`` last read it, by resolved path."""


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _asset_path(asset: str) -> Path:
    """``ASSETS_DIR / asset``, refused with the path when the file is not there."""
    path = ASSETS_DIR / asset
    if not path.is_file():
        raise FileNotFoundError(f"robot asset {path} not found (config asset={asset!r})")
    return path


CURRICULUM_SUMS = ("tracking_sum", "command_sq_sum", "error_sq_sum")
"""Per-env sums over the episode (or command period) that the command curriculum judges
(``LeggedEnv.tracked``): the ``tracking_lin_vel`` kernel, the squared planar command, and the
squared planar velocity error. Kept in the env's info only with ``commands.curriculum``."""


@dataclass(frozen=True)
class CommandConfig:
    """Ranges of the sampled velocity commands (uniform)."""

    lin_vel_x: tuple[float, float] = (-1.0, 1.0)
    """Forward velocity command range, m/s (base frame)."""
    lin_vel_y: tuple[float, float] = (-1.0, 1.0)
    """Lateral velocity command range, m/s."""
    yaw_rate: tuple[float, float] = (-1.0, 1.0)
    """Yaw-rate command range, rad/s."""
    resample_time_s: float = 10.0
    """Commands are resampled this often within an episode (and at every reset)."""
    zero_below: float = 0.2
    """Planar commands with norm below this become exactly zero (legged_gym), so the
    policy also learns to stand still."""
    zero_share: float = 0.0
    """Share of sampled commands set to exactly (0, 0, 0), yaw included, so that standing
    still under a zero command is trained on purpose (0: off, and the command stream is the
    same as without the option)."""
    turn_share: float = 0.0
    """Share of sampled commands made turns in place: the planar part set to zero, the yaw rate
    kept as drawn from ``yaw_rate``. Without it, only the draws whose planar part falls below
    ``zero_below`` turn in place (about a quarter under XBot-L's ranges). Disjoint from
    ``zero_share`` (one draw decides: below ``zero_share`` zero, then below ``zero_share +
    turn_share`` a turn), so the two must sum to at most 1. Measured on Cassie at 0.5
    (docs/command_grid.md, stop 48): it made one of two seed roots turn, and only once the
    policy already walked. The quadrupeds' ``stand_still`` term reads only the planar command
    and so also holds the pose under a turn in place: leave its weight at 0 with this option.
    0: off, and the command stream is the same as without the option."""
    curriculum: bool = False
    """Command curriculum, kept per env. legged_gym widens one global forward range whenever the
    resetting envs' mean velocity-tracking kernel tops 0.8; here every env carries its own level
    in [``curriculum_start``, 1], as legged_gym's terrain curriculum carries a terrain level, so
    the rule stays local to the env and vmaps. Each env samples its commands from the three ranges
    above scaled by its level. An episode that times out with a mean ``tracking_lin_vel`` kernel of
    at least ``curriculum_threshold`` raises the level by ``curriculum_step`` (1: the full ranges);
    a fall lowers it by the same. The trainer logs the mean level as ``step_command_level``. Off:
    the command stream is unchanged."""
    curriculum_start: float = 0.3
    """The level every env starts at: its commands span this fraction of each range."""
    curriculum_step: float = 0.1
    """How far one episode moves an env's level."""
    curriculum_threshold: float = 0.8
    """The bar an episode (or command period) must reach to raise its env's level, read by
    ``curriculum_judge``: with ``kernel``, the mean per-step ``tracking_lin_vel`` kernel (exp of
    the squared planar velocity error, 1 at perfect tracking; legged_gym's 0.8); with ``gain``,
    the share of the command's planar speed tracked, 1 - sum |command - v|^2 / sum |command|^2."""
    curriculum_judge: str = "kernel"
    """What counts as tracking well enough to raise the level. ``kernel`` (legged_gym's): the mean
    tracking kernel. A robot that stands earns most of that kernel under small commands (Go2,
    sigma 0.25: 0.85 at 0.2 m/s, 1 under the zero commands of ``zero_below``), so a standing
    policy raises its level too (measured: 0.3 to 0.58 in 240 iterations, docs/command_grid.md).
    ``gain``: 1 - sum |command - v|^2 / sum |command|^2 over the episode or period, 0 for a robot
    that stands and 1 for one that tracks; a period whose command was zero throughout moves
    nothing up."""
    curriculum_update: str = "episode"
    """When the level moves. ``episode``: only where an episode ends, judged on the whole
    episode's mean kernel (once most envs survive whole episodes they end together, every
    ``episode_length_s``). ``resample``: also at every command resample within an episode
    (``resample_time_s``), judged on the mean kernel since the last resample, so the level can
    rise once per command; the level reached is drawn from at once, a fall still lowers it at the
    episode end, and a time-out is judged on its last command period."""

    def __post_init__(self):
        for name in ("curriculum_start", "curriculum_step", "curriculum_threshold"):
            if not 0.0 < getattr(self, name) <= 1.0:
                raise ValueError(f"commands.{name} must lie in (0, 1], got {getattr(self, name)}")
        for name in ("lin_vel_x", "lin_vel_y", "yaw_rate"):
            lo, hi = getattr(self, name)
            if lo > hi:
                raise ValueError(f"commands.{name}: low {lo} > high {hi}")
        if self.curriculum_update not in ("episode", "resample"):
            raise ValueError(f"commands.curriculum_update must be 'episode' or 'resample', got {self.curriculum_update!r}")
        if self.curriculum_judge not in ("kernel", "gain"):
            raise ValueError(f"commands.curriculum_judge must be 'kernel' or 'gain', got {self.curriculum_judge!r}")
        if not 0.0 <= self.zero_share <= 1.0:
            raise ValueError(f"commands.zero_share must lie in [0, 1], got {self.zero_share}")
        if not 0.0 <= self.turn_share <= 1.0:
            raise ValueError(f"commands.turn_share must lie in [0, 1], got {self.turn_share}")
        if self.zero_share + self.turn_share > 1.0:
            raise ValueError(
                f"commands.zero_share + commands.turn_share must be at most 1, got "
                f"{self.zero_share} + {self.turn_share}"
            )
        if self.resample_time_s <= 0:
            raise ValueError(f"commands.resample_time_s must be > 0, got {self.resample_time_s}")


@dataclass(frozen=True)
class LocomotionConfig:
    """Settings shared by every legged robot. Families extend it with their reward weights."""

    asset: str = ""
    """MJCF file name in ``assets/``."""
    sim_dt: float = 0.005
    """Physics time step, s."""
    decimation: int = 4
    """Physics steps per policy step; policy rate = 1 / (sim_dt * decimation)."""
    episode_length_s: float = 20.0
    """Episodes are truncated (time-out, bootstrapped) after this long."""
    kp: tuple[float, ...] = (40.0,)
    """Proportional PD gain per joint, N m / rad (one value broadcasts to all joints)."""
    kd: tuple[float, ...] = (0.5,)
    """Derivative PD gain per joint, N m s / rad (written into the model's joint damping)."""
    action_scale: float = 0.25
    """Joint target = default pose + action_scale * action, rad."""
    clip_actions: float = 100.0
    """Raw actions are clipped to +-this before scaling (legged_gym's clip_actions)."""
    solver_iterations: int = 4
    """MJX constraint solver iterations (cost grows with them). On Go2 in a dynamic state (a
    random PD target change), one 10 ms step with 2 iterations left joint velocities 1.7 rad/s
    from the converged solution, and MJX and MuJoCo C disagreed by as much; with 4 both converged
    (agreement 4e-6) at 12 % more MJX cost (512 envs). Standing alone hid this (0.3 mm)."""
    ls_iterations: int = 4
    """MJX line-search iterations."""
    implicit_damping: bool = True
    """Integrate joint damping (the PD law's Kd) implicitly (MuJoCo's Euler 'eulerdamp').
    Needed for high-Kd light joints at a 5 ms step; explicit is cheaper where it is stable."""
    termination_height: float = 0.15
    """The episode ends (no bootstrap) when the base origin drops below this height, m."""
    max_tilt_rad: float = 1.0
    """... or when the base tilts further than this from upright, rad."""
    init_joint_noise: float = 0.1
    """Initial joint angles: default pose + U(-x, x), rad."""
    init_base_vel_noise: float = 0.2
    """Initial base linear and angular velocity: U(-x, x) per axis."""
    init_heading_range: float = 0.0
    """Initial heading of the base: turned about the vertical by U(-x, x) rad at every reset, at
    most pi. 0: every episode starts facing +x, as in legged_gym and humanoid-gym (and the PRNG
    stream is the same as without the option). The bipeds observe their heading (base_euler's
    yaw), so from one start heading a policy can learn to hold it against every yaw command:
    TRON1 turned back to heading 0 from 1.5 rad off within a second, at up to 2.4 rad/s, and
    never followed a yaw command (docs/command_grid.md, stop 55). Rewards and commands read
    velocities in the base frame, so they do not change with the heading."""
    only_positive_rewards: bool = True
    """Clip the total reward at zero (legged_gym, humanoid-gym): avoids learning to fall early."""
    commands: CommandConfig = field(default_factory=CommandConfig)
    """Velocity command sampling."""
    randomization: RandomizationConfig = field(default_factory=RandomizationConfig)
    """Domain randomization (``envs.randomization``); off unless enabled."""
    engine: str = "mjx"
    """Physics engine: ``mjx`` (MJX, in JAX: GPU or CPU) or ``mujoco`` (MuJoCo C's batched
    stepper on the CPU's threads, through a host callback; ``envs.mujoco_engine``). The env's
    own code is the same for both."""
    joint_roles: tuple[str, ...] = ()
    """Each actuated joint's role, ``"<limb>:<kind>"`` in actuator order (``envs.semantics``:
    limbs FL FR RL RR or L R; kinds hip_roll, hip_yaw, hip_pitch, knee, tarsus, ankle_pitch,
    ankle_roll). The semantic transfer maps joints of two robots by role; the sign of each
    joint's axis is read from the model. Empty: the robot takes no part in semantic transfers."""

    def __post_init__(self):
        if self.sim_dt <= 0 or self.decimation < 1:
            raise ValueError(f"sim_dt must be > 0 and decimation >= 1, got {self.sim_dt}, {self.decimation}")
        if self.episode_length_s < self.sim_dt * self.decimation:
            raise ValueError(f"episode_length_s={self.episode_length_s} is shorter than one policy step")
        if self.solver_iterations < 1 or self.ls_iterations < 1:
            raise ValueError("solver_iterations and ls_iterations must be >= 1")
        if any(k < 0 for k in self.kp) or any(k < 0 for k in self.kd):
            raise ValueError("PD gains kp and kd must be >= 0")
        if not 0.0 <= self.init_heading_range <= np.pi:
            raise ValueError(f"init_heading_range must lie in [0, pi] rad, got {self.init_heading_range}")
        if self.engine not in ENGINES:
            raise ValueError(f"engine must be one of {ENGINES}, got {self.engine!r}")

    @property
    def ctrl_dt(self) -> float:
        return self.sim_dt * self.decimation

    @property
    def episode_steps(self) -> int:
        return int(round(self.episode_length_s / self.ctrl_dt))


def load_mj_model(cfg: LocomotionConfig) -> mujoco.MjModel:
    """Load the asset and apply the config's physics settings to it."""
    path = _asset_path(cfg.asset)
    digest = _sha256(path.read_bytes())  # the version this process trains on (asset_sha256)
    model = mujoco.MjModel.from_xml_path(str(path))
    _LOADED_DIGESTS[path.resolve()] = digest
    model.opt.timestep = cfg.sim_dt
    model.opt.iterations = cfg.solver_iterations
    model.opt.ls_iterations = cfg.ls_iterations
    eulerdamp = int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    if cfg.implicit_damping:
        model.opt.disableflags &= ~eulerdamp
    else:
        model.opt.disableflags |= eulerdamp
    nu = model.nu
    model.dof_damping[6:] = _per_joint(cfg.kd, nu, "kd")
    return model


def _per_joint(values: tuple[float, ...], n: int, name: str) -> np.ndarray:
    v = np.asarray(values, np.float32)
    if v.size == 1:
        return np.full(n, float(v[0]), np.float32)
    if v.size != n:
        raise ValueError(f"{name} has {v.size} values; the robot has {n} joints (give 1 or {n})")
    return v


class StepInfo(NamedTuple):
    """What a trainer reads of a stepped ``State`` beyond obs, reward and metrics: the env's
    half of the contract with ``ptrl_jax.core.train`` (``StepInfo.of(state)``). The values live in
    ``state.info`` (Brax's wrappers need a dict there); this record names and types them."""

    termination: jax.Array
    """1.0 where the step ended the episode by a fall or non-finite physics (no bootstrap)."""
    truncation: jax.Array
    """1.0 where the step ended the episode by its time limit (the value bootstraps)."""
    final_obs: dict
    """The observation the step reached, before an auto-reset replaced ``state.obs``."""
    nonfinite: jax.Array
    """1.0 where the physics state became non-finite (the env was reset)."""

    @classmethod
    def of(cls, state: State) -> "StepInfo":
        info = state.info
        return cls(info["termination"], info["truncation"], info["final_obs"], info["nonfinite"])


class StepOutcome(NamedTuple):
    """What ``LeggedEnv.evaluate_transition`` returns: one step's outcome before any reset."""

    obs: dict
    reward: jax.Array
    metrics: dict
    info: dict
    termination: jax.Array
    """Fell (or non-finite physics): the episode ends with no bootstrap."""
    truncation: jax.Array
    """Time-out: the episode ends and the value bootstraps."""
    reset_key: jax.Array
    """Randomness for the auto-reset that follows a done step."""


def load_system(mj_model: mujoco.MjModel):
    """Brax's MJX ``System`` for ``mj_model``, its arrays on this process's first device.

    Brax's ``mjcf.load_model`` calls ``mjx.put_model(mj)``, which places the model on
    ``jax.devices()[0]``. In one process that is the first local device; under
    ``jax.distributed`` it is process 0's, which the other processes cannot address, and their
    compile then fails ("Closing over jax.Array that spans non-addressable devices"). The call is
    made with ``put_model`` bound to ``jax.local_devices()[0]``, which is the same device in a
    single process."""
    put_model = mjx.put_model
    mjx.put_model = functools.partial(put_model, device=jax.local_devices()[0])
    try:
        return mjcf.load_model(mj_model)
    finally:
        mjx.put_model = put_model


class LeggedEnv(PipelineEnv):
    """Base class: PD control, commands, termination, auto-reset and reward bookkeeping."""

    def __init__(self, config: LocomotionConfig, **kwargs):
        self.config = config
        mj_model = load_mj_model(config)
        self.mj_model = mj_model
        sys = load_system(mj_model)
        super().__init__(sys, backend="mjx", n_frames=config.decimation, **kwargs)
        # MJX's initial data as host constants: mjx.make_data places its arrays on
        # jax.devices()[0], which under jax.distributed is process 0's device (issue 22), so the
        # reset builds its data from these arrays, placed nowhere, instead of calling it.
        self._data0 = jax.tree.map(np.asarray, mjx.make_data(sys, device=jax.local_devices()[0]))

        self.num_joints = mj_model.nu
        key = mj_model.key("home")
        self._default_qpos = jnp.asarray(key.qpos, jnp.float32)
        self._default_joints = self._default_qpos[7:]
        self._kp = jnp.asarray(_per_joint(config.kp, self.num_joints, "kp"))
        self._kd = jnp.asarray(_per_joint(config.kd, self.num_joints, "kd"))
        self._torque_limit = jnp.asarray(mj_model.actuator_ctrlrange[:, 1], jnp.float32)
        lo, hi = mj_model.jnt_range[1:, 0], mj_model.jnt_range[1:, 1]
        self._joint_lower = jnp.asarray(lo, jnp.float32)
        self._joint_upper = jnp.asarray(hi, jnp.float32)
        self._base_body = int(mj_model.jnt_bodyid[0])  # the free joint's body
        self._stepper = MujocoStepper(mj_model, self._base_body) if config.engine == "mujoco" else None
        # A family may offer several reward sets (the biped's reward_set); the chosen one's weights.
        rewards = config.active_rewards if hasattr(config, "active_rewards") else config.rewards  # type: ignore
        self._reward_weights: Mapping[str, float] = dataclasses.asdict(rewards)
        if config.commands.curriculum and "tracking_lin_vel" not in self._reward_weights:
            raise ValueError(f"commands.curriculum reads the tracking_lin_vel reward term, which {config.asset}'s "
                             f"rewards do not have (terms: {sorted(self._reward_weights)})")
        self.joint_names = [mj_model.joint(j).name for j in range(1, mj_model.njnt)]
        self.joint_roles = (semantics.parse_roles(config.joint_roles, self.joint_names, config.asset)
                            if config.joint_roles else ())
        self.joint_signs = (semantics.joint_axis_signs(mj_model, self.joint_roles)
                            if self.joint_roles else None)

    @functools.cached_property
    def joint_flexion_signs(self):
        """Per actuated joint: ``joint_signs``, except that a knee gets its flexion direction in
        its own coordinates (``semantics.knee_flexion_signs``); None without joint roles."""
        if not self.joint_roles:
            return None
        return semantics.knee_flexion_signs(self.mj_model, self.joint_roles, self.joint_signs,
                                            self.declared_flexion())

    def declared_flexion(self) -> dict[int, float]:
        """Joint index -> the sign in which the family says that joint flexes (used for knees
        that are straight at home). None declared by default."""
        return {}

    @property
    def reward_names(self) -> tuple[str, ...]:
        """The reward terms, in the order ``metrics`` logs them as ``reward/<name>``."""
        return tuple(self._reward_weights)

    # ----- to be provided by a family -------------------------------------------------------
    family_name = "legged"
    """The family's name; entries that only compare within a family (base height) carry it."""

    def observation_blocks(self) -> dict[str, list[semantics.ObsBlock]]:
        """What each entry of each observation key means, in ``_observe``'s order."""
        raise NotImplementedError

    def _init_family_info(self, data: Any, rng: jax.Array) -> dict:
        return {}

    def _step_features(self, data: Any, info: dict) -> dict[str, jax.Array]:
        """Quantities that more than one of ``_reward_terms``, ``_after_step_info`` and
        ``_observe`` read (foot contact, a gait reference), computed once per step and passed to
        each. ``info`` is the step's, after its step counter advanced."""
        return {}

    def _observe(self, data: Any, info: dict, features: dict | None = None) -> tuple[dict[str, jax.Array], dict]:
        """Return ({"state", "privileged_state"}, updated info) for the current data;
        ``features`` is ``_step_features(data, info)`` (computed here when not given: at reset)."""
        raise NotImplementedError

    def _reward_terms(self, data: Any, action: jax.Array, info: dict, features: dict) -> dict[str, jax.Array]:
        raise NotImplementedError

    def _after_step_info(self, data: Any, info: dict, features: dict) -> dict:
        """Family bookkeeping after rewards (e.g. feet air time)."""
        return info

    # ----- shared kinematics ------------------------------------------------------------------
    @staticmethod
    def base_quat(data) -> jax.Array:
        return data.qpos[3:7]

    def projected_gravity(self, data) -> jax.Array:
        return math.inv_rotate(jnp.array([0.0, 0.0, -1.0]), self.base_quat(data))

    def base_lin_vel(self, data) -> jax.Array:
        """Base linear velocity in the base frame (free-joint qvel[0:3] is in the world frame)."""
        return math.inv_rotate(data.qvel[0:3], self.base_quat(data))

    @staticmethod
    def base_ang_vel(data) -> jax.Array:
        """Base angular velocity in the base frame (MuJoCo's free-joint qvel[3:6] already is)."""
        return data.qvel[3:6]

    @staticmethod
    def joint_pos(data) -> jax.Array:
        return data.qpos[7:]

    @staticmethod
    def joint_vel(data) -> jax.Array:
        return data.qvel[6:]

    # ----- commands ---------------------------------------------------------------------------
    def sample_command(self, rng: jax.Array, level: jax.Array | float = 1.0) -> jax.Array:
        """A command drawn from the config's ranges; with ``commands.curriculum`` the ranges are
        scaled by ``level`` (the env's curriculum level; ignored without it)."""
        c = self.config.commands
        lo = jnp.array([c.lin_vel_x[0], c.lin_vel_y[0], c.yaw_rate[0]])
        hi = jnp.array([c.lin_vel_x[1], c.lin_vel_y[1], c.yaw_rate[1]])
        if c.curriculum:  # static: without it the ranges are the config's as they stand
            lo, hi = lo * level, hi * level
        cmd = jax.random.uniform(rng, (3,), minval=lo, maxval=hi)
        planar = jnp.linalg.norm(cmd[:2]) >= c.zero_below
        cmd = cmd.at[:2].multiply(planar)
        if c.zero_share > 0 or c.turn_share > 0:  # static: without them the uniform draw stands
            # One draw decides both shares (bernoulli(key, p) is this same draw compared to p).
            u = jax.random.uniform(jax.random.fold_in(rng, 1))
            turn = (u >= c.zero_share) & (u < c.zero_share + c.turn_share)
            cmd = cmd.at[:2].multiply(~turn)
            cmd = jnp.where(u < c.zero_share, 0.0, cmd)
        return cmd

    # ----- reset --------------------------------------------------------------------------------
    def _initial_qpos_qvel(self, rng: jax.Array) -> tuple[jax.Array, jax.Array]:
        k_q, k_v = jax.random.split(rng)
        cfg = self.config
        joint_noise = jax.random.uniform(k_q, (self.num_joints,), minval=-1.0, maxval=1.0)
        qpos = self._default_qpos.at[7:].add(cfg.init_joint_noise * joint_noise)
        qpos = qpos.at[7:].set(jnp.clip(qpos[7:], self._joint_lower, self._joint_upper))
        base_vel = jax.random.uniform(k_v, (6,), minval=-1.0, maxval=1.0) * cfg.init_base_vel_noise
        qvel = jnp.zeros(self.sys.nv).at[:6].set(base_vel)
        if cfg.init_heading_range > 0.0:  # static; off, the draws above are the only ones
            yaw = jax.random.uniform(jax.random.fold_in(rng, 2), (), minval=-1.0, maxval=1.0) * cfg.init_heading_range
            turn = jnp.array([jnp.cos(yaw / 2), 0.0, 0.0, jnp.sin(yaw / 2)])
            qpos = qpos.at[3:7].set(math.quat_mul(turn, qpos[3:7]))
        return qpos, qvel

    def tracked(self, info: dict, steps: jax.Array) -> jax.Array:
        """Whether the ``steps`` steps that ``info``'s sums cover (the episode, or the command
        period) tracked well enough to raise the level, by ``commands.curriculum_judge``:
        ``kernel``: the mean ``tracking_lin_vel`` kernel (``tracking_sum / steps``) is at least
        ``curriculum_threshold``; ``gain``: ``1 - error_sq_sum / command_sq_sum`` is, and some
        command was not zero."""
        c = self.config.commands
        if c.curriculum_judge == "kernel":  # static
            return info["tracking_sum"] / jnp.maximum(steps, 1) >= c.curriculum_threshold
        command = info["command_sq_sum"]
        return (command > 0.0) & (info["error_sq_sum"] <= (1.0 - c.curriculum_threshold) * command)

    def next_command_level(self, level: jax.Array, tracked: jax.Array, fell: jax.Array,
                           timed_out: jax.Array) -> jax.Array:
        """The curriculum's rule (``CommandConfig.curriculum``) for an env whose episode just
        ended: up one step on a time-out that ``tracked`` (see ``tracked``), down one on a fall,
        else unchanged; clipped to [``curriculum_start``, 1]."""
        c = self.config.commands
        up = timed_out & tracked
        moved = level + c.curriculum_step * (up.astype(jnp.float32) - fell.astype(jnp.float32))
        return jnp.clip(moved, c.curriculum_start, 1.0).astype(jnp.float32)

    def curriculum_steps(self, step: jax.Array) -> jax.Array:
        """The steps the curriculum's sums cover at episode step ``step`` (1, 2, ...): the whole
        episode, or with ``curriculum_update=resample`` the steps since the last resample."""
        if self.config.commands.curriculum_update == "episode":
            return step
        return (step - 1) % self._resample_steps + 1

    @property
    def _resample_steps(self) -> int:
        return int(round(self.config.commands.resample_time_s / self.config.ctrl_dt))

    def _fresh_info(self, data, rng: jax.Array, level: jax.Array | None = None) -> dict:
        """A new episode's info; ``level``: the env's curriculum level (``curriculum_start``
        when None; read only with ``commands.curriculum``)."""
        rng, k_cmd, k_family = jax.random.split(rng, 3)
        curriculum = self.config.commands.curriculum
        if level is None:
            level = jnp.asarray(self.config.commands.curriculum_start, jnp.float32)
        info = {
            "rng": rng,
            "command": self.sample_command(k_cmd, level),
            "last_action": jnp.zeros(self.num_joints),
            "last_joint_vel": self.joint_vel(data),
            "step": jnp.zeros((), jnp.int32),
            "truncation": jnp.zeros(()),
            "termination": jnp.zeros(()),
            "nonfinite": jnp.zeros(()),
        }
        if curriculum:
            info["command_level"] = level
            for k in CURRICULUM_SUMS:
                info[k] = jnp.zeros(())
        if self.config.randomization.enabled:
            k_family, k_draw = jax.random.split(k_family)
            info["randomization"] = randomization.sample(self.config.randomization, k_draw)
        info.update(self._init_family_info(data, k_family))
        return info

    def reset(self, rng: jax.Array) -> State:
        rng, k_init = jax.random.split(rng)
        qpos, qvel = self._initial_qpos_qvel(k_init)
        # Kinematics only (body and site poses for the first observation): a full mjx.forward
        # here would compile the collision and constraint pipeline a second time, and the
        # first mjx.step recomputes all of it anyway.
        data = jax.tree.map(jnp.asarray, self._data0).replace(qpos=qpos, qvel=qvel)
        data = mjx.kinematics(self.sys, data)
        info = self._fresh_info(data, rng)
        obs, info = self._observe(data, info)
        info["final_obs"] = obs
        zero = jnp.zeros(())
        metrics = {f"reward/{k}": zero for k in self._reward_weights}
        if self.config.commands.curriculum:
            metrics["command_level"] = info["command_level"]
        return State(data, obs, zero, zero, metrics, info)

    def reset_with_command(self, rng: jax.Array, command: jax.Array) -> State:
        """``reset``, then the joystick set to ``command`` (vx, vy, yaw rate) in place of the
        sampled one, with the first observation recomputed from it (a biped's frame stack is
        still filled with that one frame at step 0). vmappable over commands; the command is
        resampled only as the config's ``commands.resample_time_s`` says."""
        state = self.reset(rng)
        info = {**state.info, "command": jnp.asarray(command, jnp.float32).reshape(3)}
        obs, info = self._observe(state.pipeline_state, info)
        info["final_obs"] = obs
        return state.replace(obs=obs, info=info)

    # ----- step ---------------------------------------------------------------------------------
    def joint_targets(self, action: jax.Array) -> jax.Array:
        a = jnp.clip(action, -self.config.clip_actions, self.config.clip_actions)
        return self._default_joints + self.config.action_scale * a

    def pd_torque(self, data, target: jax.Array, kp_scale=1.0, motor_strength=1.0) -> jax.Array:
        """Stiffness half of the PD law; the damping half is implicit joint damping. The scales
        are domain randomization's (1 without it)."""
        tau = kp_scale * self._kp * (target - self.joint_pos(data))
        return motor_strength * jnp.clip(tau, -self._torque_limit, self._torque_limit)

    def physics_step(self, data, action: jax.Array, info: dict):
        """``decimation`` physics steps under the PD law; ``info`` carries the episode's domain
        randomization draw (read only when randomization is enabled)."""
        target = self.joint_targets(action)
        sys, kp_scale, strength, draw = self.sys, 1.0, 1.0, None
        if self.config.randomization.enabled:
            draw = info["randomization"]
            if self._stepper is None:
                sys = randomization.apply(self.sys, draw, self._base_body)
            kp_scale, strength = draw["kp_scale"], draw["motor_strength"]
            data = self._push(data, info)

        def substep(d, _):
            # mjx.step on plain mjx.Data: Brax's pipeline wrapper would also rebuild its own
            # link transforms and contacts every substep, which nothing here reads.
            tau = self.pd_torque(d, target, kp_scale, strength)
            if self._stepper is not None:  # engine=mujoco: MuJoCo C applies the same draw
                return self._stepper.step(d.replace(ctrl=tau), draw), None
            return mjx.step(sys, d.replace(ctrl=tau)), None

        data, _ = jax.lax.scan(substep, data, None, length=self.config.decimation)
        return data

    def _push(self, data, info: dict):
        """Domain randomization's push: every push_interval_s of an episode, a random change of
        the base's planar velocity (world frame)."""
        cfg = self.config.randomization
        every = max(int(round(cfg.push_interval_s / self.config.ctrl_dt)), 1)
        due = (info["step"] > 0) & (info["step"] % every == 0)
        kick = jax.random.uniform(jax.random.fold_in(info["rng"], 1), (2,), minval=-1.0, maxval=1.0)
        return data.replace(qvel=data.qvel.at[:2].add(jnp.where(due, cfg.max_push_vel * kick, 0.0)))

    def fell(self, data) -> jax.Array:
        too_low = data.qpos[2] < self.config.termination_height
        tilted = self.projected_gravity(data)[2] > -jnp.cos(self.config.max_tilt_rad)
        return too_low | tilted

    def evaluate_transition(self, data, action: jax.Array, info: dict) -> "StepOutcome":
        """Everything a step computes after the physics: rewards, observation, termination,
        truncation and command resampling. Pure in ``data`` (anything with qpos, qvel, xpos and
        site_xpos), so the MuJoCo C view (``envs.gym_env``) shares these definitions exactly."""
        cfg = self.config
        info = dict(info)
        info.pop("final_obs", None)
        info["step"] = info["step"] + 1

        nonfinite = ~(jnp.all(jnp.isfinite(data.qpos)) & jnp.all(jnp.isfinite(data.qvel)))
        features = self._step_features(data, info)  # once per step, read by the three below
        terms = self._reward_terms(data, action, info, features)
        # Explicit float32: a weakly-typed leaf (from Python-scalar arithmetic) would change the
        # state's type after one step and make every jitted caller compile a second time.
        weighted = {
            k: jnp.asarray(self._reward_weights[k] * v * cfg.ctrl_dt, jnp.float32) for k, v in terms.items()
        }
        reward = sum(weighted.values())
        if cfg.only_positive_rewards:
            reward = jnp.maximum(reward, 0.0)
        reward = jnp.where(nonfinite, 0.0, reward).astype(jnp.float32)
        metrics = {f"reward/{k}": jnp.where(nonfinite, 0.0, v) for k, v in weighted.items()}
        if cfg.commands.curriculum:
            metrics["command_level"] = info["command_level"]
            planar = info["command"][:2]
            error = planar - self.base_lin_vel(data)[:2]
            for k, v in (("tracking_sum", terms["tracking_lin_vel"]), ("command_sq_sum", jnp.sum(planar**2)),
                         ("error_sq_sum", jnp.sum(error**2))):
                info[k] = (info[k] + jnp.where(nonfinite, 0.0, v)).astype(jnp.float32)

        info = self._after_step_info(data, info, features)
        info["last_action"] = jnp.asarray(action, jnp.float32)
        info["last_joint_vel"] = self.joint_vel(data)
        obs, info = self._observe(data, info, features)
        obs = jax.tree.map(lambda x: jnp.where(jnp.isfinite(x), x, 0.0), obs)

        termination = self.fell(data) | nonfinite
        truncation = (info["step"] >= cfg.episode_steps) & ~termination

        # Commands are resampled on a fixed period within an episode.
        rng, k_cmd, k_reset = jax.random.split(info["rng"], 3)
        info["rng"] = rng
        resample = (info["step"] % self._resample_steps) == 0
        level = info.get("command_level", 1.0)
        c = cfg.commands
        if c.curriculum and c.curriculum_update == "resample":  # static
            # A resample within the episode judges the command period that ends here; the level
            # it reaches is the one the next command is drawn from. Episode ends are step()'s.
            within = resample & ~termination & ~truncation
            up = within & self.tracked(info, self.curriculum_steps(info["step"]))
            level = jnp.clip(level + c.curriculum_step * up.astype(jnp.float32), c.curriculum_start, 1.0)
            info["command_level"] = level.astype(jnp.float32)
            for k in CURRICULUM_SUMS:
                info[k] = jnp.where(within, 0.0, info[k]).astype(jnp.float32)
        info["command"] = jnp.where(resample, self.sample_command(k_cmd, level), info["command"])
        info["truncation"] = truncation.astype(jnp.float32)
        info["termination"] = termination.astype(jnp.float32)
        info["nonfinite"] = nonfinite.astype(jnp.float32)
        return StepOutcome(obs, reward, metrics, info, termination, truncation, k_reset)

    def step(self, state: State, action: jax.Array) -> State:
        data = self.physics_step(state.pipeline_state, action, state.info)
        t = self.evaluate_transition(data, action, state.info)
        done = t.termination | t.truncation

        # Auto-reset: rewrite the state where the episode ended.
        qpos0, qvel0 = self._initial_qpos_qvel(t.reset_key)
        reset_data = data.replace(
            qpos=jnp.where(done, qpos0, data.qpos),
            qvel=jnp.where(done, qvel0, data.qvel),
            qacc_warmstart=jnp.where(done, 0.0, data.qacc_warmstart),
        )
        level = None
        if self.config.commands.curriculum:  # the ended episode moves its env's level
            level = self.next_command_level(t.info["command_level"],
                                            self.tracked(t.info, self.curriculum_steps(t.info["step"])),
                                            t.termination, t.truncation)
        reset_info = self._fresh_info(reset_data, t.reset_key, level)
        reset_obs, reset_info = self._observe(reset_data, reset_info)
        for k in ("truncation", "termination", "nonfinite"):
            reset_info[k] = t.info[k]
        # Only the env's own keys reset: wrappers (Brax's EpisodeWrapper, AutoResetWrapper) keep
        # theirs in the same dict, and their values pass through.
        info = {**t.info, **{k: jax.tree.map(lambda r, c: jnp.where(done, r, c), v, t.info[k])
                             for k, v in reset_info.items()}}
        next_obs = jax.tree.map(lambda r, c: jnp.where(done, r, c), reset_obs, t.obs)
        info["final_obs"] = t.obs
        metrics = {**state.metrics, **t.metrics}  # a wrapper's own metrics keys pass through
        return State(reset_data, next_obs, t.reward, done.astype(jnp.float32), metrics, info)

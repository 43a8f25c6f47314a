"""The biped family, after humanoid-gym's XBot-L setup: XBot-L, MIT Humanoid, Cassie and TRON1,
one config each.

Observation frame (11 + 3n for n joints: 47 for 12), humanoid-gym's order and scales:
    sin and cos of the gait phase (2), command * (2, 2, 1) (3), joint positions relative to the
    default pose (n), joint velocities * 0.05 (n), last action (n), base angular velocity (3),
    base roll-pitch-yaw (3).
The actor sees the last ``frame_stack`` frames (15 in humanoid-gym: 705 dims). The critic sees
the current frame plus privileged state: base linear velocity * 2, base height, the reference
stance mask, foot contacts and the joint error to the reference gait.

Reference gait (humanoid-gym ``compute_ref_state``): with phase p = t / cycle_time and
s = sin(2 pi p), the left leg swings while s < 0 and the right while s > 0; in swing the hip
pitch, knee and ankle pitch targets are (s, 2s, s) * target_joint_pos_scale on the signed axes,
and both legs stand while |s| < 0.1 (double support).

Rewards: humanoid-gym's XBot-L terms (see ``BipedRewards``), except ``feet_contact_forces``
and ``collision``, which need contact forces / collision geometry we leave out for MJX speed
(documented in the README). Foot contact is geometric: sole height below ``contact_height``.
``reward_set=point_foot`` pays tron1-rl-isaacgym's terms instead (``PointFootRewards``), TRON1's own.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
from brax import math
from jax.scipy.stats import norm

from envs import semantics
from envs.base import CommandConfig, LeggedEnv, LocomotionConfig
from envs.randomization import RandomizationConfig


@dataclass(frozen=True)
class BipedRewards:
    """Reward weights (times the policy dt). humanoid-gym XBotLCfg values; 0 disables a term."""

    joint_pos: float = 1.6
    """exp(-2 |q - q_ref|) - 0.2 clip(|q - q_ref|, 0, 0.5): follow the reference gait."""
    feet_clearance: float = 1.0
    """Swing feet within 1 cm of target_feet_height."""
    feet_contact_number: float = 1.2
    """mean over feet of (1 if contact matches the reference stance else -0.3)."""
    feet_air_time: float = 1.0
    """sum_feet clip(t_air, 0, 0.5) at touchdown."""
    foot_slip: float = -0.05
    """sum_feet sqrt(|v_foot,xy|) while in contact."""
    feet_distance: float = 0.2
    """Keep the feet between min_feet_distance and max_feet_distance apart."""
    knee_distance: float = 0.2
    """Keep the knees between min_feet_distance and max_feet_distance / 2 apart."""
    tracking_lin_vel: float = 1.2
    """exp(-sigma |v_xy^cmd - v_xy|^2)."""
    tracking_ang_vel: float = 1.1
    """exp(-sigma (w_z^cmd - w_z)^2)."""
    vel_mismatch_exp: float = 0.5
    """(exp(-10 v_z^2) + exp(-5 |w_xy|)) / 2."""
    low_speed: float = 0.2
    """+1.2 within [0.5, 1.2] x the commanded vx, -1 too slow, -2 wrong sign."""
    track_vel_hard: float = 0.5
    """(exp(-10 |e_v|) + exp(-10 |e_w|)) / 2 - 0.2 (|e_v| + |e_w|)."""
    default_joint_pos: float = 0.5
    """exp(-100 clip(|hip yaw,roll error| - 0.1, 0)) - 0.01 |q - q_default|."""
    orientation: float = 1.0
    """(exp(-10 |roll, pitch|) + exp(-20 |g_xy|)) / 2."""
    base_height: float = 0.2
    """exp(-100 |h - base_height_target|), h measured from the stance feet."""
    base_acc: float = 0.2
    """exp(-3 |a_base|) with a_base the per-step change of base velocity."""
    action_smoothness: float = -0.002
    """First and second differences of actions, plus 0.05 |a|."""
    torques: float = -1e-5
    """|tau|^2."""
    dof_vel: float = -5e-4
    """|qdot|^2."""
    dof_acc: float = -1e-7
    """|qddot|^2."""


# Constants of tron1-rl-isaacgym's pointfoot_flat rewards (limxdynamics/tron1-rl-isaacgym d26da7f,
# envs/pointfoot_flat/pointfoot_flat_config.py: rewards.*).
POINT_FOOT_LIN_SIGMA = 0.2  # tracking_sigma: exp(-error^2 / sigma)
POINT_FOOT_ANG_SIGMA = 0.25  # ang_tracking_sigma
POINT_FOOT_GAIT_VEL_SIGMA = 0.25  # gait_vel_sigma, m^2/s^2
POINT_FOOT_KAPPA = 0.05  # kappa_gait_probs: width of the smoothed contact schedule, in cycles
POINT_FOOT_LANDING_HEIGHT = 0.08  # about_landing_threshold, m
POINT_FOOT_SOFT_LIMIT = 0.95  # soft_dof_pos_limit: share of each joint range before the penalty


@dataclass(frozen=True)
class PointFootRewards:
    """tron1-rl-isaacgym's pointfoot_flat reward weights (times the policy dt), paid with
    ``reward_set=point_foot``. Its gait clock is this family's (fixed ``cycle_time``, the left
    foot's stance in the first half of each cycle, the right's in the second; the source draws
    a frequency in 1.5-2.5 Hz per episode). Left out: ``collision`` (knee and hip contact forces),
    and the source's clipping of each weighted term to +-5 and of the sum to +-100."""

    keep_balance: float = 1.0
    """1 per step alive."""
    tracking_lin_vel: float = 1.0
    """exp(-|v_xy^cmd - v_xy|^2 / 0.2)."""
    tracking_ang_vel: float = 0.5
    """exp(-(w_z^cmd - w_z)^2 / 0.25)."""
    base_height: float = -2.0
    """(h - base_height_target)^2, h the base height above the flat ground."""
    lin_vel_z: float = -0.5
    """v_z^2."""
    ang_vel_xy: float = -0.05
    """|w_xy|^2."""
    torques: float = -8e-5
    """|tau|^2."""
    dof_acc: float = -2.5e-7
    """|qddot|^2."""
    action_rate: float = -0.01
    """|a - a'|^2."""
    action_smooth: float = -0.01
    """|a - 2a' + a''|^2 (the actions' curvature)."""
    dof_pos_limits: float = -2.0
    """How far each joint is beyond 95 % of its range (about its centre), summed."""
    orientation: float = -10.0
    """|g_xy|^2 of the projected gravity."""
    feet_distance: float = -100.0
    """clip(min_feet_distance - d_feet,xy, 0, 1)."""
    feet_regulation: float = -0.05
    """sum_feet exp(-h_foot / (0.001 base_height_target)) |v_foot,xy|^2: no sliding near the ground."""
    foot_landing_vel: float = -0.15
    """sum_feet v_foot,z^2 for a foot in the air, under 8 cm and descending."""
    tracking_contacts_shaped_force: float = -2.0
    """mean_feet (1 - desired contact) (1 - exp(-F^2 / 25)): force in the desired swing. The foot's
    geometric contact stands for the force factor (it is 1 within 0.2 % above 13 N)."""
    tracking_contacts_shaped_vel: float = -2.0
    """mean_feet desired contact (1 - exp(-|v_foot|^2 / 0.25)): foot speed in the desired stance."""


def smoothed_stance(phase: jax.Array) -> jax.Array:
    """The desired contact of a foot whose stance is the first half of each gait cycle: the
    source's Normal(0, kappa) CDF smoothing of the schedule (1 in stance, 0 in swing, 0.5 at the
    switches). ``phase`` in cycles, any real."""
    x = jnp.mod(phase, 1.0)
    cdf = lambda t: norm.cdf(t, scale=POINT_FOOT_KAPPA)  # noqa: E731
    return cdf(x) * (1.0 - cdf(x - 0.5)) + cdf(x - 1.0) * (1.0 - cdf(x - 1.5))


@dataclass(frozen=True)
class BipedConfig(LocomotionConfig):
    """A biped: ``LocomotionConfig`` plus gait and foot settings."""

    frame_stack: int = 15
    """Observation frames stacked for the actor (humanoid-gym: 15)."""
    euler_order: str = "xyz"
    """The convention of base_euler (observed, and read by the orientation term). ``xyz``: Brax's
    ``quat_to_euler`` (intrinsic x-y'-z''), whose roll and pitch are tilts about the world's axes,
    so one body tilt reads differently at another heading (pitch 0.1, roll 0.05 read roll -0.10,
    pitch -0.05 at heading 2.5 rad). ``zyx``: yaw, then pitch, then roll (humanoid-gym's
    get_euler_xyz), whose roll and pitch are the body's, whatever the heading. ``xyz`` is what
    every biped so far was trained on; with ``zyx`` and ``observe_heading=false`` a TRON1 policy met
    every grid goal and turned (docs/command_grid.md, stop 55; one seed)."""
    observe_heading: bool = True
    """Whether base_euler's yaw, the base's heading in the world, is observed (humanoid-gym's
    layout). False: that entry reads 0 in every frame, actor's and critic's, and the layout stays.
    A velocity-command policy needs no heading (legged_gym's and Playground's joystick policies
    see none), and with it TRON1's policies learned to hold one heading against every yaw command
    (docs/command_grid.md, stop 55)."""
    cycle_time: float = 0.64
    """Gait period, s."""
    target_joint_pos_scale: float = 0.17
    """Amplitude of the reference gait, rad."""
    target_feet_height: float = 0.06
    """Swing-foot clearance target, m."""
    contact_height: float = 0.02
    """A foot is in contact when its sole is below this height, m."""
    tracking_sigma: float = 5.0
    """Sharpness of the exponential tracking rewards."""
    base_height_target: float = 0.89
    """Target base height above the stance feet, m."""
    min_feet_distance: float = 0.2
    """Lower bound of the feet_distance reward band, m."""
    max_feet_distance: float = 0.5
    """Upper bound of the feet_distance reward band, m."""
    swing_joints: tuple[int, ...] = (2, 3, 4, 8, 9, 10)
    """The reference gait's joints, left leg then right, the same count per leg (XBot-L: hip
    pitch, knee, ankle pitch)."""
    swing_signs: tuple[float, ...] = (-1.0, -1.0, -1.0, 1.0, 1.0, 1.0)
    """Sign of flexion on each swing joint (XBot-L's axes are mirrored: left flexes negative)."""
    swing_gains: tuple[float, ...] = (1.0, 2.0, 1.0, 1.0, 2.0, 1.0)
    """Swing amplitude per joint in units of target_joint_pos_scale (humanoid-gym: hip 1, knee 2,
    ankle 1, which keeps the sole parallel to the ground)."""
    hip_yaw_roll_joints: tuple[int, ...] = (0, 1, 6, 7)
    """Hip roll and yaw joints, left then right, held near default by default_joint_pos."""
    foot_sites: tuple[str, str] = ("left_foot_site", "right_foot_site")
    """Sites at the sole centres."""
    knee_bodies: tuple[str, str] = ("left_knee_link", "right_knee_link")
    """Bodies whose origins are the knees (for knee_distance)."""
    rewards: BipedRewards = field(default_factory=BipedRewards)
    """Reward weights of ``reward_set=humanoid_gym``."""
    reward_set: str = "humanoid_gym"
    """The terms the env pays: ``humanoid_gym`` (``rewards``, humanoid-gym's XBot-L set, the
    family's) or ``point_foot`` (``point_foot_rewards``, tron1-rl-isaacgym's pointfoot_flat set,
    written for TRON1; that source also pays negative rewards: set ``only_positive_rewards=false``)."""
    point_foot_rewards: PointFootRewards = field(default_factory=PointFootRewards)
    """Reward weights of ``reward_set=point_foot``."""

    def __post_init__(self):
        super().__post_init__()
        if self.reward_set not in REWARD_SETS:
            raise ValueError(f"reward_set must be one of {REWARD_SETS}, got {self.reward_set!r}")
        if self.euler_order not in ("xyz", "zyx"):
            raise ValueError(f"euler_order must be 'xyz' or 'zyx', got {self.euler_order!r}")

    @property
    def active_rewards(self):
        """The weights of the chosen ``reward_set``."""
        return self.point_foot_rewards if self.reward_set == "point_foot" else self.rewards


REWARD_SETS = ("humanoid_gym", "point_foot")


class RewardInputs(NamedTuple):
    """The per-step quantities both reward sets read (``BipedEnv._reward_inputs``)."""

    cmd: jax.Array
    """The command (vx, vy, yaw rate)."""
    v: jax.Array
    """Base linear velocity, base frame."""
    w: jax.Array
    """Base angular velocity, base frame."""
    g: jax.Array
    """Projected gravity."""
    q: jax.Array
    """Joint positions."""
    qd: jax.Array
    """Joint velocities."""
    tau: jax.Array
    """PD torques of this step's action."""
    foot_pos: jax.Array
    """Sole sites, world frame, [2, 3]."""
    foot_vel: jax.Array
    """Their finite-difference velocities, [2, 3] (zero on an episode's first step)."""
    valid_history: jax.Array
    """Whether the finite differences span a step of this episode."""

# humanoid-gym XBotLCfg's command ranges, used for every biped (the checks are at vx 0 and 0.3).
BIPED_COMMANDS = CommandConfig(
    lin_vel_x=(-0.3, 0.6), lin_vel_y=(-0.3, 0.3), yaw_rate=(-0.3, 0.3), resample_time_s=8.0
)

XBOT_L_CONFIG = BipedConfig(
    asset="xbot_l.xml",
    sim_dt=0.005,
    decimation=2,  # 100 Hz policy, as humanoid-gym
    episode_length_s=24.0,
    kp=(200.0, 200.0, 350.0, 350.0, 15.0, 15.0) * 2,
    kd=(10.0,),
    action_scale=0.25,
    termination_height=0.55,
    max_tilt_rad=0.8,
    init_joint_noise=0.05,
    init_base_vel_noise=0.1,
    commands=BIPED_COMMANDS,
    # humanoid-gym XBotLCfg.domain_rand as recalled (not in FACTS.md): off until an experiment
    # enables it.
    randomization=RandomizationConfig(friction=(0.1, 2.0), added_base_mass=(-5.0, 5.0),
                                      push_interval_s=4.0, max_push_vel=0.2),
    joint_roles=("L:hip_roll", "L:hip_yaw", "L:hip_pitch", "L:knee", "L:ankle_pitch", "L:ankle_roll",
                 "R:hip_roll", "R:hip_yaw", "R:hip_pitch", "R:knee", "R:ankle_pitch", "R:ankle_roll"),
)


# MIT Humanoid, after pbrs-humanoid's humanoid_config.py (FACTS §8): kp 30 / kd 5 on all ten
# joints, action_scale 1.0, 100 Hz, base_height_target 0.62 (a crouch below the 0.69 stand).
# Its hips have yaw, abad, pitch; the sagittal chain is hip pitch, knee, ankle on +y axes on both
# legs, so flexion signs are not mirrored (assets/README.md, joint table).
MIT_HUMANOID_CONFIG = BipedConfig(
    asset="mit_humanoid.xml",
    sim_dt=0.005,
    decimation=2,  # 100 Hz, as pbrs-humanoid
    episode_length_s=24.0,
    kp=(30.0,),
    kd=(5.0,),
    action_scale=1.0,
    termination_height=0.4,
    max_tilt_rad=0.8,
    init_joint_noise=0.05,
    init_base_vel_noise=0.1,
    base_height_target=0.62,
    # Shorter legs than XBot-L: 0.3 rad of hip swing lifts the sole 3.8 cm (0.17 gives 1.6 cm).
    target_joint_pos_scale=0.3,
    target_feet_height=0.04,
    min_feet_distance=0.12,  # feet 0.158 m apart at home
    max_feet_distance=0.35,
    swing_joints=(2, 3, 4, 7, 8, 9),
    swing_signs=(-1.0, 1.0, -1.0, -1.0, 1.0, -1.0),
    hip_yaw_roll_joints=(0, 1, 5, 6),
    commands=BIPED_COMMANDS,
    joint_roles=("L:hip_yaw", "L:hip_roll", "L:hip_pitch", "L:knee", "L:ankle_pitch",
                 "R:hip_yaw", "R:hip_roll", "R:hip_pitch", "R:knee", "R:ankle_pitch"),
)

# Cassie as legged_gym's 12-DOF open tree (cassie_config.py, FACTS §6(b)): 50 Hz, action_scale
# 0.5. The reference gait swings hip pitch and knee by equal angles, which keeps the foot level
# on Cassie's geometry (tarsus and toe keep their defaults; the tarsus is passive on the real
# robot). Every sagittal axis is -y on both legs, so the hip flexes + and the knee -. The 0.4 rad
# amplitude lifts the foot 4.4 cm.
CASSIE_CONFIG = BipedConfig(
    asset="cassie.xml",
    sim_dt=0.005,
    decimation=4,  # 50 Hz, as legged_gym
    episode_length_s=24.0,
    kp=(100.0, 100.0, 200.0, 200.0, 200.0, 40.0) * 2,
    kd=(3.0, 3.0, 6.0, 6.0, 6.0, 1.0) * 2,
    action_scale=0.5,
    termination_height=0.5,
    max_tilt_rad=0.8,
    init_joint_noise=0.05,
    init_base_vel_noise=0.1,
    base_height_target=0.85,  # the 0.855 m stand
    target_joint_pos_scale=0.4,
    target_feet_height=0.045,
    min_feet_distance=0.2,  # feet 0.261 m apart at home
    max_feet_distance=0.45,
    swing_joints=(2, 3, 8, 9),
    swing_signs=(1.0, -1.0, 1.0, -1.0),
    swing_gains=(1.0, 1.0, 1.0, 1.0),
    hip_yaw_roll_joints=(0, 1, 6, 7),
    commands=BIPED_COMMANDS,
    joint_roles=("L:hip_roll", "L:hip_yaw", "L:hip_pitch", "L:knee", "L:tarsus", "L:ankle_pitch",
                 "R:hip_roll", "R:hip_yaw", "R:hip_pitch", "R:knee", "R:tarsus", "R:ankle_pitch"),
)

# TRON1 point foot (PF_TRON1A), after tron1-rl-isaacgym pointfoot_flat_config.py (FACTS §9):
# kp 42 / kd 2.5, action_scale 0.25, 50 Hz, feet_height_target 0.10, min_feet_distance 0.115,
# the source's base_height_target is 0.68, a crouch 13 cm below the stand (base 0.812 m above the
# point feet at the zero pose), under legged_gym's squared penalty, whose gradient reaches the
# stand. Under this family's exp(-100 |h - target|) that target paid 2e-6 at the stand, a term the
# policy could not climb, so ours is TRON1's own stand. No ankle: the gait swings hip and knee only. The zero pose has the
# knee bent 60 degrees, and on the left leg + on both hip and knee lifts the foot (right mirrored);
# checked by forward kinematics: 0.17 rad gives 5.9 cm of lift, 0.25 rad about 0.1 m.
TRON1_CONFIG = BipedConfig(
    asset="tron1.xml",
    sim_dt=0.005,
    decimation=4,  # 50 Hz, as the source
    episode_length_s=24.0,
    kp=(42.0,),
    kd=(2.5,),
    action_scale=0.25,
    termination_height=0.45,
    max_tilt_rad=0.8,
    init_joint_noise=0.05,
    init_base_vel_noise=0.1,
    target_joint_pos_scale=0.25,
    target_feet_height=0.10,
    base_height_target=0.81,  # its stand, 0.812 m (tests/test_envs.py::TestBaseHeightTargets)
    min_feet_distance=0.115,  # feet 0.21 m apart at home
    max_feet_distance=0.4,
    swing_joints=(1, 2, 4, 5),
    swing_signs=(1.0, 1.0, -1.0, -1.0),
    swing_gains=(1.0, 2.0, 1.0, 2.0),
    hip_yaw_roll_joints=(0, 3),  # abad only: TRON1 has no hip yaw
    commands=BIPED_COMMANDS,
    joint_roles=("L:hip_roll", "L:hip_pitch", "L:knee", "R:hip_roll", "R:hip_pitch", "R:knee"),
)


class BipedEnv(LeggedEnv):
    config: BipedConfig
    family_name = "biped"

    def _frame_blocks(self, frame: int) -> list[semantics.ObsBlock]:
        joints = range(self.num_joints)
        suffix = f"[t-{frame}]" if frame else ""
        blocks = [
            semantics.block("gait_clock", "clock", ("sin", "cos"), 1.0),
            semantics.block("command", "command", ("vx", "vy", "yaw"), (2.0, 2.0, 1.0)),
            semantics.block("joint_pos", "joint_pos", joints, 1.0),
            semantics.block("joint_vel", "joint_vel", joints, 0.05),
            semantics.block("last_action", "last_action", joints, 1.0 / self.config.action_scale),
            semantics.block("base_ang_vel", "ang_vel", "xyz", 1.0),
            semantics.ObsBlock("base_euler", (
                semantics.ObsEntry("tilt", "roll"), semantics.ObsEntry("tilt", "pitch"),
                semantics.ObsEntry("heading", "yaw"))),
        ]
        return [semantics.ObsBlock(b.name + suffix, tuple(e._replace(frame=frame) for e in b.entries))
                for b in blocks]

    def observation_blocks(self):
        """The layout ``_observe`` writes (module docstring): the actor's frames oldest first."""
        state = [b for age in reversed(range(self.config.frame_stack)) for b in self._frame_blocks(age)]
        privileged = [
            *self._frame_blocks(0),
            semantics.block("base_lin_vel", "lin_vel", "xyz", 2.0),
            semantics.block("base_height", "height", (self.family_name,), 1.0),
            semantics.block("stance", "stance", ("L", "R"), 1.0),
            semantics.block("foot_contact", "contact", ("L", "R"), 1.0),
            semantics.block("joint_ref_err", "joint_ref_err", range(self.num_joints), 1.0),
        ]
        return {"state": state, "privileged_state": privileged}

    def declared_flexion(self) -> dict[int, float]:
        """The reference gait's swing sign of each swing joint: the direction it flexes to lift the
        foot (a straight home knee's flexion direction, ``semantics.knee_flexion_signs``)."""
        return {int(j): float(s) for j, s in zip(self.config.swing_joints, self.config.swing_signs)}

    def __init__(self, config: BipedConfig, **kwargs):
        super().__init__(config, **kwargs)
        m = self.mj_model
        n = self.num_joints
        swing = (config.swing_joints, config.swing_signs, config.swing_gains)
        if len({len(t) for t in swing}) != 1 or len(config.swing_joints) % 2:
            raise ValueError(
                f"{config.asset}: swing_joints, swing_signs and swing_gains need one entry per joint, "
                f"the same count per leg; got {tuple(len(t) for t in swing)}")
        for name in ("swing_joints", "hip_yaw_roll_joints"):
            idx = getattr(config, name)
            if any(not 0 <= i < n for i in idx) or len(idx) % 2:
                raise ValueError(f"{config.asset}: {name}={idx} must be joint indices in [0, {n}), "
                                 f"left leg then right")
        self._foot_sites = jnp.array([m.site(name).id for name in config.foot_sites])
        self._knee_bodies = jnp.array([m.body(name).id for name in config.knee_bodies])
        self._swing_idx = jnp.array(config.swing_joints)
        self._swing_sign = jnp.array(config.swing_signs)
        self._swing_gain = jnp.array(config.swing_gains)
        half = len(config.hip_yaw_roll_joints) // 2
        self._hip_left = jnp.array(config.hip_yaw_roll_joints[:half])
        self._hip_right = jnp.array(config.hip_yaw_roll_joints[half:])

    # ----- gait -----------------------------------------------------------------------------------
    def phase(self, info) -> jax.Array:
        return info["step"] * self.config.ctrl_dt / self.config.cycle_time

    def reference(self, info) -> tuple[jax.Array, jax.Array]:
        """(reference joint positions, stance mask [left, right])."""
        s = jnp.sin(2.0 * jnp.pi * self.phase(info))
        left_swing, right_swing = jnp.maximum(-s, 0.0), jnp.maximum(s, 0.0)
        per_leg = len(self.config.swing_joints) // 2
        swing = jnp.concatenate([jnp.full(per_leg, left_swing), jnp.full(per_leg, right_swing)])
        amplitude = self.config.target_joint_pos_scale * self._swing_gain * self._swing_sign * swing
        amplitude = jnp.where(jnp.abs(s) < 0.1, 0.0, amplitude)
        ref = self._default_joints.at[self._swing_idx].add(amplitude)
        stance = jnp.array([s >= 0.0, s < 0.0]) | (jnp.abs(s) < 0.1)
        return ref, stance

    def foot_contact(self, data) -> jax.Array:
        return data.site_xpos[self._foot_sites, 2] < self.config.contact_height

    # ----- observations ---------------------------------------------------------------------------
    def _init_family_info(self, data, rng):
        return {
            "obs_history": jnp.zeros((self.config.frame_stack, self.frame_size)),
            "feet_air_time": jnp.zeros(2),
            "last_contact": jnp.zeros(2, bool),
            "last_foot_pos": data.site_xpos[self._foot_sites],
            "last_last_action": jnp.zeros(self.num_joints),
            "last_base_vel": data.qvel[:6],
        }

    @property
    def frame_size(self) -> int:
        return 2 + 3 + 3 * self.num_joints + 3 + 3

    def _frame(self, data, info) -> jax.Array:
        p = 2.0 * jnp.pi * self.phase(info)
        return jnp.concatenate(
            [
                jnp.array([jnp.sin(p), jnp.cos(p)]),
                info["command"] * jnp.array([2.0, 2.0, 1.0]),
                self.joint_pos(data) - self._default_joints,
                self.joint_vel(data) * 0.05,
                info["last_action"],
                self.base_ang_vel(data),
                self._observed_euler(data),
            ]
        )

    def _observed_euler(self, data) -> jax.Array:
        """base_euler as the frame carries it: the heading read as 0 unless ``observe_heading``."""
        euler = self.base_euler(data)
        return euler if self.config.observe_heading else euler.at[2].set(0.0)  # static branch

    def base_euler(self, data) -> jax.Array:
        """(roll, pitch, yaw) of the base in ``euler_order``'s convention."""
        q = self.base_quat(data)
        if self.config.euler_order == "xyz":  # static
            return math.quat_to_euler(q)
        w, x, y, z = q[0], q[1], q[2], q[3]
        roll = jnp.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
        pitch = jnp.arcsin(jnp.clip(2.0 * (w * y - z * x), -1.0, 1.0))
        yaw = jnp.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
        return jnp.stack([roll, pitch, yaw])

    def _step_features(self, data, info):
        ref, stance = self.reference(info)
        contact = self.foot_contact(data)
        return {"reference": ref, "stance": stance, "contact": contact,
                # a foot down now, due down by the gait, or down the step before
                "contact_filt": contact | stance | info["last_contact"],
                "air_time": info["feet_air_time"] + self.config.ctrl_dt}

    def _observe(self, data, info, features=None):
        frame = self._frame(data, info)
        shifted = jnp.concatenate([info["obs_history"][1:], frame[None]], axis=0)
        filled = jnp.broadcast_to(frame, info["obs_history"].shape)
        history = jnp.where(info["step"] == 0, filled, shifted)
        info = {**info, "obs_history": history}
        features = self._step_features(data, info) if features is None else features
        ref, stance = features["reference"], features["stance"]
        privileged = jnp.concatenate(
            [
                frame,
                self.base_lin_vel(data) * 2.0,
                data.qpos[2:3],
                stance.astype(jnp.float32),
                features["contact"].astype(jnp.float32),
                self.joint_pos(data) - ref,
            ]
        )
        return {"state": history.reshape(-1), "privileged_state": privileged}, info

    # ----- rewards --------------------------------------------------------------------------------
    def _reward_inputs(self, data, action, info):
        """What both reward sets read: command, base velocities (base frame), projected gravity,
        joint positions and velocities, PD torques, foot positions and their finite-difference
        velocities (zero on an episode's first step), and whether those differences are valid."""
        qd = self.joint_vel(data)
        tau = self.pd_torque(data, self.joint_targets(action)) - self._kd * qd
        foot_pos = data.site_xpos[self._foot_sites]
        valid_history = info["step"] > 1  # finite differences need one step of this episode
        foot_vel = jnp.where(valid_history, (foot_pos - info["last_foot_pos"]) / self.config.ctrl_dt, 0.0)
        return RewardInputs(info["command"], self.base_lin_vel(data), self.base_ang_vel(data),
                            self.projected_gravity(data), self.joint_pos(data), qd, tau, foot_pos, foot_vel,
                            valid_history)

    def _reward_terms(self, data, action, info, features):
        if self.config.reward_set == "point_foot":  # static
            return self._point_foot_terms(data, action, info, features)
        cfg = self.config
        cmd, v, w, g, q, qd, tau, foot_pos, foot_vel, valid_history = self._reward_inputs(data, action, info)
        ref, stance, contact = features["reference"], features["stance"], features["contact"]
        foot_speed = jnp.linalg.norm(foot_vel[:, :2], axis=-1)

        diff = jnp.linalg.norm(q - ref)
        joint_pos = jnp.exp(-2.0 * diff) - 0.2 * jnp.clip(diff, 0.0, 0.5)

        swing = jnp.where(stance, 0.0, 1.0)
        clearance = jnp.where(jnp.abs(foot_pos[:, 2] - cfg.target_feet_height) < 0.01, 1.0, 0.0)
        air_time = features["air_time"]
        first_contact = (info["feet_air_time"] > 0.0) & features["contact_filt"]

        def band(dist, lo, hi):
            d_min = jnp.clip(dist - lo, -0.5, 0.0)
            d_max = jnp.clip(dist - hi, 0.0, 0.5)
            return 0.5 * (jnp.exp(-jnp.abs(d_min) * 100.0) + jnp.exp(-jnp.abs(d_max) * 100.0))

        feet_dist = jnp.linalg.norm(foot_pos[0, :2] - foot_pos[1, :2])
        knees = data.xpos[self._knee_bodies]
        knee_dist = jnp.linalg.norm(knees[0, :2] - knees[1, :2])

        lin_err = jnp.linalg.norm(cmd[:2] - v[:2])
        ang_err = jnp.abs(cmd[2] - w[2])

        speed, command_x = jnp.abs(v[0]), jnp.abs(cmd[0])
        too_low, too_high = speed < 0.5 * command_x, speed > 1.2 * command_x
        low_speed = jnp.where(too_low, -1.0, jnp.where(too_high, 0.0, 1.2))
        low_speed = jnp.where(v[0] * cmd[0] < 0.0, -2.0, low_speed)
        low_speed = jnp.where(command_x > 0.1, low_speed, 0.0)

        q_err = q - self._default_joints
        yaw_roll = jnp.linalg.norm(q_err[self._hip_left]) + jnp.linalg.norm(q_err[self._hip_right])
        yaw_roll = jnp.clip(yaw_roll - 0.1, 0.0, 50.0)

        euler = self.base_euler(data)
        stance_f = stance.astype(jnp.float32)
        stance_height = jnp.sum(foot_pos[:, 2] * stance_f) / jnp.maximum(jnp.sum(stance_f), 1.0)
        base_acc = jnp.where(valid_history, jnp.linalg.norm(info["last_base_vel"] - data.qvel[:6]), 0.0)

        a, a1, a2 = action, info["last_action"], info["last_last_action"]
        return {
            "joint_pos": joint_pos,
            "feet_clearance": jnp.sum(clearance * swing),
            "feet_contact_number": jnp.mean(jnp.where(contact == stance, 1.0, -0.3)),
            "feet_air_time": jnp.sum(jnp.clip(air_time, 0.0, 0.5) * first_contact),
            "foot_slip": jnp.sum(jnp.sqrt(foot_speed + 1e-8) * contact),
            "feet_distance": band(feet_dist, cfg.min_feet_distance, cfg.max_feet_distance),
            "knee_distance": band(knee_dist, cfg.min_feet_distance, cfg.max_feet_distance / 2.0),
            "tracking_lin_vel": jnp.exp(-jnp.sum((cmd[:2] - v[:2]) ** 2) * cfg.tracking_sigma),
            "tracking_ang_vel": jnp.exp(-((cmd[2] - w[2]) ** 2) * cfg.tracking_sigma),
            "vel_mismatch_exp": 0.5 * (jnp.exp(-10.0 * v[2] ** 2) + jnp.exp(-5.0 * jnp.linalg.norm(w[:2]))),
            "low_speed": low_speed,
            "track_vel_hard": 0.5 * (jnp.exp(-10.0 * lin_err) + jnp.exp(-10.0 * ang_err)) - 0.2 * (lin_err + ang_err),
            "default_joint_pos": jnp.exp(-100.0 * yaw_roll) - 0.01 * jnp.linalg.norm(q - self._default_joints),
            "orientation": 0.5 * (jnp.exp(-10.0 * jnp.sum(jnp.abs(euler[:2]))) + jnp.exp(-20.0 * jnp.linalg.norm(g[:2]))),
            "base_height": jnp.exp(-100.0 * jnp.abs(data.qpos[2] - stance_height - cfg.base_height_target)),
            "base_acc": jnp.exp(-3.0 * base_acc),
            "action_smoothness": jnp.sum((a1 - a) ** 2) + jnp.sum((a + a2 - 2.0 * a1) ** 2) + 0.05 * jnp.sum(jnp.abs(a)),
            "torques": jnp.sum(tau**2),
            "dof_vel": jnp.sum(qd**2),
            "dof_acc": jnp.sum(((qd - info["last_joint_vel"]) / cfg.ctrl_dt) ** 2),
        }

    def _point_foot_terms(self, data, action, info, features):
        """``PointFootRewards``' terms (tron1-rl-isaacgym's ``_reward_*``), on flat ground."""
        cfg = self.config
        cmd, v, w, g, q, qd, tau, foot_pos, foot_vel, _ = self._reward_inputs(data, action, info)
        contact = features["contact"].astype(jnp.float32)
        foot_height = jnp.clip(foot_pos[:, 2], 0.0, 1.0)  # the sites are at the soles

        phase = self.phase(info)
        desired = jnp.stack([smoothed_stance(phase), smoothed_stance(phase + 0.5)])

        centre, half = (self._joint_upper + self._joint_lower) / 2, (self._joint_upper - self._joint_lower) / 2
        lower, upper = centre - POINT_FOOT_SOFT_LIMIT * half, centre + POINT_FOOT_SOFT_LIMIT * half
        beyond = jnp.clip(lower - q, 0.0, None) + jnp.clip(q - upper, 0.0, None)

        landing = (foot_height < POINT_FOOT_LANDING_HEIGHT) & (contact == 0.0) & (foot_vel[:, 2] < 0.0)
        a, a1, a2 = action, info["last_action"], info["last_last_action"]
        feet_dist = jnp.linalg.norm(foot_pos[0, :2] - foot_pos[1, :2])
        return {
            "keep_balance": jnp.ones(()),
            "tracking_lin_vel": jnp.exp(-jnp.sum((cmd[:2] - v[:2]) ** 2) / POINT_FOOT_LIN_SIGMA),
            "tracking_ang_vel": jnp.exp(-((cmd[2] - w[2]) ** 2) / POINT_FOOT_ANG_SIGMA),
            "base_height": (data.qpos[2] - cfg.base_height_target) ** 2,
            "lin_vel_z": v[2] ** 2,
            "ang_vel_xy": jnp.sum(w[:2] ** 2),
            "torques": jnp.sum(tau**2),
            "dof_acc": jnp.sum(((qd - info["last_joint_vel"]) / cfg.ctrl_dt) ** 2),
            "action_rate": jnp.sum((a - a1) ** 2),
            "action_smooth": jnp.sum((a - 2.0 * a1 + a2) ** 2),
            "dof_pos_limits": jnp.sum(beyond),
            "orientation": jnp.sum(g[:2] ** 2),
            "feet_distance": jnp.clip(cfg.min_feet_distance - feet_dist, 0.0, 1.0),
            "feet_regulation": jnp.sum(jnp.exp(-foot_height / (0.001 * cfg.base_height_target))
                                       * jnp.sum(foot_vel[:, :2] ** 2, axis=-1)),
            "foot_landing_vel": jnp.sum(jnp.where(landing, foot_vel[:, 2] ** 2, 0.0)),
            "tracking_contacts_shaped_force": jnp.mean((1.0 - desired) * contact),
            "tracking_contacts_shaped_vel": jnp.mean(
                desired * (1.0 - jnp.exp(-jnp.sum(foot_vel**2, axis=-1) / POINT_FOOT_GAIT_VEL_SIGMA))),
        }

    def _after_step_info(self, data, info, features):
        info["feet_air_time"] = jnp.where(features["contact_filt"], 0.0, features["air_time"])
        info["last_contact"] = features["contact"]
        info["last_foot_pos"] = data.site_xpos[self._foot_sites]
        info["last_last_action"] = info["last_action"]
        info["last_base_vel"] = data.qvel[:6]
        return info

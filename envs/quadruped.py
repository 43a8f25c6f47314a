"""The quadruped family: Go2, A1, ANYmal B and ANYmal C, one config each.

Observation (paper Table I, 45 dims), in legged_gym's scales:
    base angular velocity * 0.25 (3), projected gravity (3), joint positions relative to the
    default pose (12), joint velocities * 0.05 (12), command * (2, 2, 0.25) (3), last action (12).
The critic additionally sees the base linear velocity * 2 (3), the base height (1) and the
foot contact flags (4): the privileged state of an asymmetric actor-critic.

Rewards: the legged_gym / unitree_rl_gym Go2 set (see ``QuadrupedRewards``); each term is
documented where it is computed. Termination (fall) is by base height and tilt, since the model
has no trunk collision geometry; see ``LocomotionConfig``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp

from envs import semantics
from envs.base import CommandConfig, LeggedEnv, LocomotionConfig

FOOT_NAMES = ("FL", "FR", "RL", "RR")

# Every quadruped here: per leg hip abduction (x axis), thigh (hip pitch) and calf (knee).
QUADRUPED_ROLES = tuple(f"{leg}:{kind}" for leg in FOOT_NAMES for kind in ("hip_roll", "hip_pitch", "knee"))


@dataclass(frozen=True)
class QuadrupedRewards:
    """Reward weights (multiplied by the policy dt, as legged_gym does). 0 disables a term."""

    tracking_lin_vel: float = 1.0
    """exp(-|v_xy^cmd - v_xy|^2 / sigma): planar velocity tracking."""
    tracking_ang_vel: float = 0.5
    """exp(-(w_z^cmd - w_z)^2 / sigma): yaw-rate tracking."""
    lin_vel_z: float = -2.0
    """v_z^2: vertical base velocity."""
    ang_vel_xy: float = -0.05
    """|w_xy|^2: roll and pitch rates."""
    orientation: float = 0.0
    """|g_xy|^2 of the projected gravity: non-flat base."""
    torques: float = -2e-4
    """|tau|^2 (unitree_rl_gym Go2 weight)."""
    dof_acc: float = -2.5e-7
    """|qddot|^2, by finite differences of joint velocity."""
    action_rate: float = -0.01
    """|a_t - a_{t-1}|^2."""
    feet_air_time: float = 1.0
    """sum_feet (t_air - 0.5) at touchdown, only while a planar command is given."""
    dof_pos_limits: float = -10.0
    """Joint-angle excursion beyond soft_dof_pos_limit of the range (unitree_rl_gym Go2)."""
    base_height: float = 0.0
    """(z - target)^2 (weight 0 in unitree_rl_gym's Go2; kept for other quadrupeds)."""
    stand_still: float = 0.0
    """|q - q_default| under a zero command."""


@dataclass(frozen=True)
class QuadrupedConfig(LocomotionConfig):
    """A quadruped: ``LocomotionConfig`` plus foot geometry and reward settings."""

    foot_radius: float = 0.022
    """Foot sphere radius, m: contact is foot-centre height < radius + contact_margin."""
    contact_margin: float = 0.01
    """Extra height under which a foot counts as in contact, m."""
    tracking_sigma: float = 0.25
    """Width of the exponential tracking rewards."""
    soft_dof_pos_limit: float = 0.9
    """Fraction of each joint range inside which no limit penalty applies."""
    base_height_target: float = 0.25
    """Target base height for the base_height term, m."""
    rewards: QuadrupedRewards = field(default_factory=QuadrupedRewards)
    """Reward weights."""


GO2_CONFIG = QuadrupedConfig(
    asset="go2.xml",
    # 10 ms x 2 = 50 Hz as legged_gym's 5 ms x 4, at half the MJX cost. Under the PD hold with a
    # 0.5 m/s push, base height stayed within 2 mm of a 2 ms-step reference over 2 s (MuJoCo C).
    sim_dt=0.01,
    decimation=2,
    kp=(40.0,),  # paper: Kp 40
    kd=(0.5,),  # paper: Kd 0.5
    action_scale=0.25,
    termination_height=0.15,
    foot_radius=0.022,
    base_height_target=0.25,
    commands=CommandConfig(lin_vel_x=(-1.0, 1.0), lin_vel_y=(-1.0, 1.0), yaw_rate=(-1.0, 1.0)),
    joint_roles=QUADRUPED_ROLES,
)

A1_CONFIG = QuadrupedConfig(
    asset="a1.xml",
    # Stands and holds its pose at a 10 ms step (MuJoCo C, lowest base height 76 % of standing
    # over 2 s), so it shares Go2's 10 ms x 2 at half of legged_gym's physics cost.
    sim_dt=0.01,
    decimation=2,
    kp=(20.0,),  # legged_gym a1_config
    kd=(0.5,),
    action_scale=0.25,
    termination_height=0.15,
    foot_radius=0.02,
    base_height_target=0.25,
    commands=GO2_CONFIG.commands,
    joint_roles=QUADRUPED_ROLES,
)

# ANYmal B and C: legged_gym's kp 80 / kd 2 and action scale 0.5, with a plain PD law (legged_gym
# replaces it by the ANYdrive actuator network by default; that network is not modelled). A 10 ms
# step is unstable for these heavier legs under Kd 2 (B sank to 55 % of its height, C was thrown
# up, MuJoCo C), so they keep legged_gym's 5 ms x 4 = 50 Hz: twice Go2's physics cost per step.
# Rewards: Table II's terms with legged_gym's base weights, since Go2's torque weight (-2e-4)
# and joint-limit weight (-10) are unitree_rl_gym's Go2 tuning for 23-45 N m motors.
_ANYMAL_REWARDS = QuadrupedRewards(torques=-1e-5, dof_pos_limits=0.0)

ANYMAL_B_CONFIG = QuadrupedConfig(
    asset="anymal_b.xml",
    sim_dt=0.005,
    decimation=4,
    kp=(80.0,),
    kd=(2.0,),
    action_scale=0.5,
    termination_height=0.25,
    foot_radius=0.031,
    base_height_target=0.5,
    rewards=_ANYMAL_REWARDS,
    commands=GO2_CONFIG.commands,
    joint_roles=QUADRUPED_ROLES,
)

ANYMAL_C_CONFIG = dataclasses.replace(ANYMAL_B_CONFIG, asset="anymal_c.xml", foot_radius=0.03)


class QuadrupedEnv(LeggedEnv):
    config: QuadrupedConfig
    family_name = "quadruped"

    def observation_blocks(self):
        """The layout ``_observe`` writes (module docstring), entry by entry."""
        joints = range(self.num_joints)
        state = [
            semantics.block("base_ang_vel", "ang_vel", "xyz", 0.25),
            # Projected gravity: (sin pitch, -sin roll cos pitch, -cos roll cos pitch), so to first
            # order x is the pitch angle and y minus the roll angle.
            semantics.ObsBlock("projected_gravity", (
                semantics.ObsEntry("tilt", "pitch", 1.0), semantics.ObsEntry("tilt", "roll", -1.0),
                semantics.ObsEntry("gravity", "z", 1.0))),
            semantics.block("joint_pos", "joint_pos", joints, 1.0),
            semantics.block("joint_vel", "joint_vel", joints, 0.05),
            semantics.block("command", "command", ("vx", "vy", "yaw"), (2.0, 2.0, 0.25)),
            semantics.block("last_action", "last_action", joints, 1.0 / self.config.action_scale),
        ]
        privileged = [
            *state,
            semantics.block("base_lin_vel", "lin_vel", "xyz", 2.0),
            semantics.block("base_height", "height", (self.family_name,), 1.0),
            semantics.block("foot_contact", "contact", FOOT_NAMES, 1.0),
        ]
        return {"state": state, "privileged_state": privileged}

    def __init__(self, config: QuadrupedConfig, **kwargs):
        super().__init__(config, **kwargs)
        m = self.mj_model
        self._foot_sites = jnp.array([m.site(f"{n}_foot_site").id for n in FOOT_NAMES])
        mid = 0.5 * (self._joint_lower + self._joint_upper)
        half = 0.5 * (self._joint_upper - self._joint_lower) * config.soft_dof_pos_limit
        self._soft_lower, self._soft_upper = mid - half, mid + half

    def foot_contact(self, data) -> jax.Array:
        z = data.site_xpos[self._foot_sites, 2]
        return z < self.config.foot_radius + self.config.contact_margin

    def _init_family_info(self, data, rng):
        return {"feet_air_time": jnp.zeros(4), "last_contact": jnp.zeros(4, bool)}

    def _step_features(self, data, info):
        contact = self.foot_contact(data)
        return {"contact": contact,
                "contact_filt": contact | info["last_contact"],  # a foot down this step or the last
                "air_time": info["feet_air_time"] + self.config.ctrl_dt}

    def _observe(self, data, info, features=None):
        features = self._step_features(data, info) if features is None else features
        cmd_scale = jnp.array([2.0, 2.0, 0.25])
        state = jnp.concatenate(
            [
                self.base_ang_vel(data) * 0.25,
                self.projected_gravity(data),
                self.joint_pos(data) - self._default_joints,
                self.joint_vel(data) * 0.05,
                info["command"] * cmd_scale,
                info["last_action"],
            ]
        )
        privileged = jnp.concatenate(
            [
                state,
                self.base_lin_vel(data) * 2.0,
                data.qpos[2:3],
                features["contact"].astype(jnp.float32),
            ]
        )
        return {"state": state, "privileged_state": privileged}, info

    def _reward_terms(self, data, action, info, features):
        cfg = self.config
        cmd = info["command"]
        v = self.base_lin_vel(data)
        w = self.base_ang_vel(data)
        g = self.projected_gravity(data)
        q = self.joint_pos(data)
        qd = self.joint_vel(data)
        tau = self.pd_torque(data, self.joint_targets(action)) - self._kd * qd

        air_time = features["air_time"]
        first_contact = (info["feet_air_time"] > 0.0) & features["contact_filt"]
        moving = jnp.linalg.norm(cmd[:2]) > 0.1
        out_of_limits = jnp.clip(self._soft_lower - q, 0.0) + jnp.clip(q - self._soft_upper, 0.0)
        return {
            "tracking_lin_vel": jnp.exp(-jnp.sum((cmd[:2] - v[:2]) ** 2) / cfg.tracking_sigma),
            "tracking_ang_vel": jnp.exp(-((cmd[2] - w[2]) ** 2) / cfg.tracking_sigma),
            "lin_vel_z": v[2] ** 2,
            "ang_vel_xy": jnp.sum(w[:2] ** 2),
            "orientation": jnp.sum(g[:2] ** 2),
            "torques": jnp.sum(tau**2),
            "dof_acc": jnp.sum(((qd - info["last_joint_vel"]) / cfg.ctrl_dt) ** 2),
            "action_rate": jnp.sum((action - info["last_action"]) ** 2),
            "feet_air_time": jnp.sum((air_time - 0.5) * first_contact) * moving,
            "dof_pos_limits": jnp.sum(out_of_limits),
            "base_height": (data.qpos[2] - cfg.base_height_target) ** 2,
            "stand_still": jnp.sum(jnp.abs(q - self._default_joints)) * (jnp.linalg.norm(cmd[:2]) < 0.1),
        }

    def _after_step_info(self, data, info, features):
        info["feet_air_time"] = jnp.where(features["contact_filt"], 0.0, features["air_time"])
        info["last_contact"] = features["contact"]
        return info

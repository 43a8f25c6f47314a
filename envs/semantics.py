"""What an env's observations and actions mean: the declarations a cross-robot transfer reads.

Every family declares its observation as a list of ``ObsEntry`` per observation key (the actor's
``state`` and the critic's ``privileged_state``), in the order ``_observe`` writes them; every
robot declares each actuated joint's role in its config (``LocomotionConfig.joint_roles``).
From these, ``ptrl_jax.core.semantic`` finds which entries and joints of two robots correspond.

The physical convention
-----------------------
- Base frame: x forward, y left, z up (MuJoCo's and Brax's).
- An entry's raw observation is ``scale * q`` where ``q`` is a physical quantity shared by all
  robots (rad, rad/s, m/s, m, or a flag). Two robots' entries of the same quantity therefore
  relate by the ratio of their scales; a negative scale says the observation is the quantity's
  negative (projected gravity's y component is minus the roll angle, to first order).
- A joint's angle is counted about its **kind's canonical axis** in the base frame at the home
  pose: +x for roll (abduction), +z for yaw, +y for every pitch-like kind (hip pitch, knee, ankle
  pitch, tarsus). The sign of a joint is the sign of its axis along that canonical axis, read
  from the model (``joint_axis_signs``), so a positive canonical angle is the same physical
  rotation on every robot: +y rotation swings a foot backwards, +x moves a left foot outwards.
- The **knee convention** differs. A knee can bend either way: Go2's knees and ANYmal's front
  knees point backwards, ANYmal's hind knees and every biped's point forwards, so the same +y
  rotation flexes one and extends the other. ``knee_flexion_signs`` therefore also gives each
  knee's *flexion* direction (the sign of its bent home angle, or the family's declared swing
  direction where the home knee is straight), so a transfer can map flexion to flexion
  (``transfer.knee=flexion``) instead of rotation to rotation (``transfer.knee=axis``).
- A joint role is ``"<limb>:<kind>"``. Limbs: ``FL FR RL RR`` (quadrupeds: front/rear,
  left/right) and ``L R`` (bipeds). Kinds: see ``JOINT_KINDS``.
"""

from __future__ import annotations

import difflib
from typing import NamedTuple

import mujoco
import numpy as np

LIMBS = ("FL", "FR", "RL", "RR", "L", "R")
"""Limb names: quadruped legs front/rear x left/right, biped legs left/right."""

JOINT_KINDS: dict[str, tuple[float, float, float]] = {
    "hip_roll": (1.0, 0.0, 0.0),
    "hip_yaw": (0.0, 0.0, 1.0),
    "hip_pitch": (0.0, 1.0, 0.0),
    "knee": (0.0, 1.0, 0.0),
    "tarsus": (0.0, 1.0, 0.0),
    "ankle_pitch": (0.0, 1.0, 0.0),
    "ankle_roll": (1.0, 0.0, 0.0),
}
"""Joint kinds and their canonical axes in the base frame (the sign convention)."""

FLEXION_KINDS = ("knee",)
"""Kinds whose flexion direction depends on which way the joint points (see the module text)."""

STRAIGHT_KNEE = 0.05
"""A home knee angle under this (rad) counts as straight: its flexion direction is not read
from the pose but from the family's declaration."""

KNEE_CONVENTIONS = ("axis", "flexion")
"""How a semantic transfer signs knees: by axis (the canonical rotation) or by flexion."""

JOINT_QUANTITIES = ("joint_pos", "joint_vel", "last_action", "joint_ref_err")
"""Per-joint quantities: an entry's ``index`` is the joint's position in the action vector."""
LIMB_QUANTITIES = ("contact", "stance")
"""Per-foot quantities: an entry's ``index`` is the limb name."""


class ObsEntry(NamedTuple):
    """One scalar of an observation vector."""

    quantity: str
    """What it measures: ang_vel, lin_vel, tilt, gravity, heading, command, clock, height,
    contact, stance, or a per-joint quantity (``JOINT_QUANTITIES``)."""
    index: str | int
    """Which component: an axis (x, y, z, roll, pitch, yaw, vx, vy), a joint index, or a limb."""
    scale: float = 1.0
    """Raw observation = scale * physical quantity (sign included)."""
    frame: int = 0
    """Age of the stacked frame it belongs to: 0 is the newest."""

    @property
    def name(self) -> str:
        age = f"[t-{self.frame}]" if self.frame else ""
        return f"{self.quantity}/{self.index}{age}"


class ObsBlock(NamedTuple):
    """A named run of entries (for documentation, maps and error messages)."""

    name: str
    entries: tuple[ObsEntry, ...]


def block(name: str, quantity: str, indices, scales, frame: int = 0) -> ObsBlock:
    """A block of one quantity over ``indices``; ``scales`` is one number or one per index."""
    indices = list(indices)
    scales = np.broadcast_to(np.asarray(scales, float), (len(indices),))
    return ObsBlock(name, tuple(ObsEntry(quantity, i, float(s), frame) for i, s in zip(indices, scales)))


def flatten(blocks: list[ObsBlock]) -> tuple[ObsEntry, ...]:
    return tuple(e for b in blocks for e in b.entries)


class JointRole(NamedTuple):
    limb: str
    kind: str

    def __str__(self) -> str:
        return f"{self.limb}:{self.kind}"


def parse_roles(roles: tuple[str, ...], joint_names: list[str], where: str) -> tuple[JointRole, ...]:
    """``("FL:hip_roll", ...)`` -> JointRoles, one per actuated joint; errors name the bad one."""
    if len(roles) != len(joint_names):
        raise ValueError(f"{where}: joint_roles has {len(roles)} entries, the robot has "
                         f"{len(joint_names)} actuated joints ({', '.join(joint_names)})")
    out = []
    for role, joint in zip(roles, joint_names):
        limb, sep, kind = str(role).partition(":")
        if not sep or limb not in LIMBS or kind not in JOINT_KINDS:
            bad = kind if limb in LIMBS else limb
            options = JOINT_KINDS if limb in LIMBS else LIMBS
            near = difflib.get_close_matches(bad, list(options), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else ""
            raise ValueError(f"{where}: joint {joint!r} has role {role!r}, not '<limb>:<kind>' with limb "
                             f"in {LIMBS} and kind in {list(JOINT_KINDS)}{hint}")
        out.append(JointRole(limb, kind))
    return tuple(out)


def joint_axis_signs(model: mujoco.MjModel, roles: tuple[JointRole, ...]) -> np.ndarray:
    """+1 or -1 per actuated joint: the sign of its axis along its kind's canonical axis, at the
    home pose, in the base frame. A joint whose axis is nearly perpendicular to its canonical
    axis (|cos| < 0.5) has a wrong kind; that is an error naming it."""
    data = mujoco.MjData(model)
    data.qpos[:] = model.key("home").qpos
    mujoco.mj_kinematics(model, data)
    base = model.jnt_bodyid[0]
    rot = data.xmat[base].reshape(3, 3)
    signs = []
    for j, role in enumerate(roles):
        axis = rot.T @ data.xaxis[j + 1]  # joints after the free joint, in actuator order
        along = float(np.dot(axis, JOINT_KINDS[role.kind]))
        if abs(along) < 0.5:
            raise ValueError(f"joint {model.joint(j + 1).name!r} is declared {role} but its axis "
                             f"{np.round(axis, 2).tolist()} is not along {JOINT_KINDS[role.kind]}")
        signs.append(1.0 if along > 0 else -1.0)
    return np.asarray(signs)


def knee_flexion_signs(model: mujoco.MjModel, roles: tuple[JointRole, ...], axis_signs: np.ndarray,
                       declared: dict[int, float] | None = None) -> np.ndarray:
    """+1 or -1 per actuated joint, in the joint's own coordinates: for a knee, the direction in
    which it flexes; for every other joint, its axis sign (``joint_axis_signs``), unchanged.

    A knee bent at home (|angle| >= ``STRAIGHT_KNEE``) flexes further the way it is bent. A knee
    straight at home takes ``declared[j]``, the family's own statement (a biped's reference-gait
    swing sign). A knee with neither, or whose declaration contradicts its bent home pose, is an
    error naming it."""
    declared = declared or {}
    home = model.key("home").qpos
    signs = np.asarray(axis_signs, float).copy()
    for j, role in enumerate(roles):
        if role.kind not in FLEXION_KINDS:
            continue
        name = model.joint(j + 1).name
        angle = float(home[model.jnt_qposadr[j + 1]])
        said = declared.get(j)
        if abs(angle) >= STRAIGHT_KNEE:
            signs[j] = 1.0 if angle > 0 else -1.0
            if said is not None and np.sign(said) != signs[j]:
                raise ValueError(f"knee {name!r} is bent {angle:+.2f} rad at home, but its family declares it "
                                 f"flexes {'+' if said > 0 else '-'} (reference-gait swing sign)")
        elif said is not None and said != 0:
            signs[j] = 1.0 if said > 0 else -1.0
        else:
            raise ValueError(f"knee {name!r} is straight at home ({angle:+.2f} rad) and its family declares "
                             f"no flexion direction for it; bend it in the home key or declare one "
                             f"(LeggedEnv.declared_flexion)")
    return signs

"""Fact checks for the biped models mit_humanoid.xml, cassie.xml and tron1.xml.

Reference numbers come from /work/shared/reference_models/FACTS.md
(section 6 "Agility Cassie", section 8 "MIT Humanoid", section 9 "LimX
Dynamics TRON1", section 10 "Notes for writing simplified MJX models") and
DERIVED_KINEMATICS.md ("DK"). Everything here runs on the MuJoCo C library
except the mjx.put_model check.
"""

import re
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mjcf_checks import check_motors, check_shared_options, colliding_pairs, pd_hold

ASSETS = Path(__file__).resolve().parents[1] / "assets"
# The source models, read at test time only to compare numbers (nothing from
# them is copied into the project); the comparison is skipped without them.
REFERENCE_MODELS = Path(__file__).resolve().parents[2] / "shared" / "reference_models"
SIDES = ("left", "right")

# ------------------------------------------------------- MIT Humanoid facts
# FACTS.md section 8: total 24.27 kg including the fixed arms; lumped torso +
# arms 13.66 kg with COM (-0.003, 0, 0.172) (also section 10).
MIT_TOTAL_MASS = 24.27
MIT_LUMPED_BASE_MASS = 13.66
MIT_LUMPED_BASE_COM = (-0.003, 0.0, 0.172)
# FACTS.md section 8: stand height 0.69 at the PBRS default angles
# (hip_pitch -0.2, knee 0.25, others 0).
MIT_STAND_HEIGHT = 0.69
MIT_HOME = [0.0, 0.0, -0.2, 0.25, 0.0] * 2
_MIT_SUFFIX = ["hip_yaw", "hip_abad", "hip_pitch", "knee", "ankle"]
MIT_JOINTS = [f"{s}_{j}" for s in SIDES for j in _MIT_SUFFIX]
# FACTS.md section 8: effort yaw 34, abad 34, pitch 72, knee 144, ankle 68.
MIT_TORQUE = [34, 34, 72, 144, 68] * 2
# FACTS.md section 8: hips +-6.28, knee [0, 3], ankle +-1.5.
MIT_RANGES = {
    "hip_yaw": (-6.28, 6.28),
    "hip_abad": (-6.28, 6.28),
    "hip_pitch": (-6.28, 6.28),
    "knee": (0.0, 3.0),
    "ankle": (-1.5, 1.5),
}
# FACTS.md section 8 / DK: axes in the base frame at the zero pose (left, right).
MIT_AXES = {
    "hip_yaw": ((0.174, 0, -0.985), (-0.174, 0, 0.985)),
    "hip_abad": ((0.966, 0, -0.259), (-0.966, 0, 0.259)),
    "hip_pitch": ((0, 1, 0), (0, 1, 0)),
    "knee": ((0, 1, 0), (0, 1, 0)),
    "ankle": ((0, 1, 0), (0, 1, 0)),
}
# DK (MIT Humanoid, zero pose): left-leg anchors; the right leg mirrors y.
MIT_ANCHORS = {
    "hip_yaw": (0.0, 0.082, 0.0),
    "hip_abad": (-0.0504, 0.082, -0.0850),
    "hip_pitch": (0.0314, 0.0792, -0.1213),
    "knee": (0.0184, 0.0792, -0.3704),
    "ankle": (0.0184, 0.0792, -0.6489),
}
# DK (MIT Humanoid, default pose): left ankle at (0.0542, 0.0792, -0.6462).
MIT_ANKLE_AT_HOME = (0.0542, 0.0792, -0.6462)
# FACTS.md sections 8 and 10: foot box 0.17 x 0.05, sole 0.04 below the ankle.
MIT_FOOT_LENGTH, MIT_FOOT_WIDTH, MIT_SOLE_DEPTH = 0.17, 0.05, 0.04
# pbrs-humanoid humanoid_config.py (FACTS.md section 8): kp 30, kd 5 on all joints.
MIT_KP, MIT_KD = 30.0, 5.0

# ------------------------------------------------------------- Cassie facts
# FACTS.md section 6(b): legged_gym cassie.urdf, 12-DOF open tree, 30.47 kg.
CASSIE_TOTAL_MASS = 30.47
# FACTS.md section 10: pelvis 10.33 kg, COM (0.051, 0, 0.028); plus the 0.1 kg
# fixed URDF base link (DK: 30.468 total - 10.33 pelvis - 2 x 10.019 per leg).
CASSIE_PELVIS_MASS = 10.33 + 0.1
CASSIE_PELVIS_COM = (0.051, 0.0, 0.028)
# FACTS.md section 6(b): stand height 0.855 at the legged_gym default angles.
CASSIE_STAND_HEIGHT = 0.855
_CASSIE_SUFFIX = ["hip_roll", "hip_yaw", "hip_pitch", "knee", "tarsus", "toe"]
CASSIE_JOINTS = [f"{s}_{j}" for s in SIDES for j in _CASSIE_SUFFIX]
# FACTS.md section 6(b): legged_gym default angles (hip_abduction +-0.1,
# hip_flexion 1.0, knee -1.8, ankle 1.57, toe -1.57).
CASSIE_HOME = [0.1, 0.0, 1.0, -1.8, 1.57, -1.57, -0.1, 0.0, 1.0, -1.8, 1.57, -1.57]
# FACTS.md section 6(b): URDF effort 112 / 112 / 195 / 195 / 195 / 45.
CASSIE_TORQUE = [112, 112, 195, 195, 195, 45] * 2
# FACTS.md section 6 / DK (legged_gym table): ranges, left and right.
CASSIE_RANGES = {
    "left_hip_roll": (-0.2618, 0.3927),
    "right_hip_roll": (-0.3927, 0.2618),
    "hip_yaw": (-0.3927, 0.3927),
    "hip_pitch": (-0.8727, 1.3963),
    "knee": (-2.8623, -0.6458),
    "tarsus": (0.6458, 2.8623),
    "toe": (-2.4435, -0.5236),
}
# DK (legged_gym table): the same axes on both legs.
CASSIE_AXES = {
    "hip_roll": (1, 0, 0),
    "hip_yaw": (0, 0, 1),
    "hip_pitch": (0, -1, 0),
    "knee": (0, -1, 0),
    "tarsus": (0, -1, 0),
    "toe": (0, -1, 0),
}
# DK (legged_gym, zero pose): left-leg anchors; the right leg mirrors y.
CASSIE_ANCHORS = {
    "hip_roll": (-0.049, 0.135, 0.0),
    "hip_yaw": (-0.049, 0.135, -0.09),
    "hip_pitch": (-0.049, 0.135, -0.09),
    "knee": (-0.049, 0.1305, -0.21),
    "tarsus": (-0.029, 0.1305, -0.6448),
    "toe": (-0.069, 0.1305, -1.0528),
}
# DK (legged_gym, default pose): left toe joint at (0.0093, 0.2097, -0.7894).
CASSIE_TOE_AT_HOME = (0.0093, 0.2097, -0.7894)
# FACTS.md section 10: Cassie foot capsule r 0.02.
CASSIE_FOOT_RADIUS = 0.02
# legged_gym cassie_config.py (FACTS.md section 6(b)).
CASSIE_KP = [100, 100, 200, 200, 200, 40] * 2
CASSIE_KD = [3, 3, 6, 6, 6, 1] * 2

# ------------------------------------------------------------- TRON1 facts
# FACTS.md section 9: URDF 18.593 kg (the MJCF, 18.233, leaves out the feet);
# base 9.585 + imu 0.01 = 9.595 with COM (0.046, 0, -0.164) (section 10).
TRON1_TOTAL_MASS = 18.593
TRON1_BASE_MASS = 9.595
TRON1_BASE_COM = (0.046, 0.0, -0.164)
# FACTS.md section 9: stand height 0.812 at the zero pose (= default angles).
TRON1_STAND_HEIGHT = 0.812
TRON1_HOME = [0.0] * 6
TRON1_JOINTS = [f"{s}_{j}_joint" for s in SIDES for j in ("abad", "hip", "knee")]
# FACTS.md section 9: effort 80 on all joints.
TRON1_TORQUE = [80] * 6
# FACTS.md section 9: ranges.
TRON1_RANGES = {
    "left_abad_joint": (-0.38397, 1.39626),
    "left_hip_joint": (-1.012291, 1.396263),
    "left_knee_joint": (-0.872665, 1.361357),
    "right_abad_joint": (-1.39626, 0.38397),
    "right_hip_joint": (-1.396263, 1.012291),
    "right_knee_joint": (-1.361357, 0.872665),
}
# FACTS.md section 9: abad +x; hip L +y / R -y; knee L -y / R +y.
TRON1_AXES = {
    "abad_joint": ((1, 0, 0), (1, 0, 0)),
    "hip_joint": ((0, 1, 0), (0, -1, 0)),
    "knee_joint": ((0, -1, 0), (0, 1, 0)),
}
# FACTS.md section 9 / DK (TRON1 table): left-leg anchors at the zero pose.
TRON1_ANCHORS = {
    "abad_joint": (0.05556, 0.105, -0.2602),
    "hip_joint": (-0.02144, 0.1255, -0.2602),
    "knee_joint": (-0.17144, 0.105, -0.52001),
}
# FACTS.md section 9: foot sphere r 0.032, centre at knee + (0.150, 0, -0.2598).
TRON1_FOOT_RADIUS = 0.032
TRON1_FOOT_FROM_KNEE = (0.150, 0.0, -0.2598)
# tron1-rl-isaacgym pointfoot_flat_config.py (FACTS.md section 9): kp 42, kd 2.5.
TRON1_KP, TRON1_KD = 42.0, 2.5


@dataclass(frozen=True)
class Robot:
    file: str
    joints: list
    torque: list
    ranges: dict  # keyed by full joint name, or by suffix (both legs)
    axes: dict  # suffix -> (left, right) axis
    anchors: dict  # suffix -> left-leg anchor at the zero pose
    home: list
    total_mass: float
    base_mass: float
    base_com: tuple
    stand_height: float
    feet: dict = field(default_factory=dict)  # side -> foot geom names
    kp: object = None
    kd: object = None

    def range_of(self, name):
        if name in self.ranges:
            return self.ranges[name]
        _, suffix = name.split("_", 1)
        return self.ranges[suffix]


MIT = Robot(
    file="mit_humanoid.xml",
    joints=MIT_JOINTS,
    torque=MIT_TORQUE,
    ranges=MIT_RANGES,
    axes=MIT_AXES,
    anchors=MIT_ANCHORS,
    home=MIT_HOME,
    total_mass=MIT_TOTAL_MASS,
    base_mass=MIT_LUMPED_BASE_MASS,
    base_com=MIT_LUMPED_BASE_COM,
    stand_height=MIT_STAND_HEIGHT,
    feet={s: [f"{s}_{p}_{q}" for p in ("heel", "toe") for q in ("outer", "inner")] for s in SIDES},
    kp=MIT_KP,
    kd=MIT_KD,
)
CASSIE = Robot(
    file="cassie.xml",
    joints=CASSIE_JOINTS,
    torque=CASSIE_TORQUE,
    ranges=CASSIE_RANGES,
    axes={k: (v, v) for k, v in CASSIE_AXES.items()},
    anchors=CASSIE_ANCHORS,
    home=CASSIE_HOME,
    total_mass=CASSIE_TOTAL_MASS,
    base_mass=CASSIE_PELVIS_MASS,
    base_com=CASSIE_PELVIS_COM,
    stand_height=CASSIE_STAND_HEIGHT,
    feet={s: [f"{s}_foot"] for s in SIDES},
    kp=CASSIE_KP,
    kd=CASSIE_KD,
)
TRON1 = Robot(
    file="tron1.xml",
    joints=TRON1_JOINTS,
    torque=TRON1_TORQUE,
    ranges=TRON1_RANGES,
    axes=TRON1_AXES,
    anchors=TRON1_ANCHORS,
    home=TRON1_HOME,
    total_mass=TRON1_TOTAL_MASS,
    base_mass=TRON1_BASE_MASS,
    base_com=TRON1_BASE_COM,
    stand_height=TRON1_STAND_HEIGHT,
    feet={s: [f"{s}_foot"] for s in SIDES},
    kp=TRON1_KP,
    kd=TRON1_KD,
)
ROBOTS = {"mit_humanoid": MIT, "cassie": CASSIE, "tron1": TRON1}


# ------------------------------------------------------------------ helpers
_MODELS: dict = {}


def _load(robot):
    if robot.file not in _MODELS:
        _MODELS[robot.file] = mujoco.MjModel.from_xml_path(str(ASSETS / robot.file))
    return _MODELS[robot.file]


@pytest.fixture(params=list(ROBOTS), ids=list(ROBOTS))
def robot(request):
    return ROBOTS[request.param]


@pytest.fixture
def model(robot):
    return _load(robot)


def _all_feet(robot):
    return [g for s in SIDES for g in robot.feet[s]]


def _lowest_point(m, d, geom):
    """World z of the lowest point of a sphere or capsule geom."""
    g = m.geom(geom)
    z = d.geom(geom).xpos[2] - g.size[0]
    if g.type[0] == mujoco.mjtGeom.mjGEOM_CAPSULE:
        axis = d.geom(geom).xmat.reshape(3, 3)[:, 2]
        z -= abs(axis[2]) * g.size[1]
    else:
        assert g.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE, f"{geom}: not a sphere or capsule"
    return z


def _lowest_foot_point(m, d, feet):
    return min(_lowest_point(m, d, f) for f in feet)


def _stand_height(m, feet, qpos=None):
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    if qpos is not None:
        d.qpos[:] = qpos
    d.qpos[2] = 2.0  # well above the floor, so nothing touches
    mujoco.mj_forward(m, d)
    return d.qpos[2] - _lowest_foot_point(m, d, feet)


def _flat_pose(m, robot, joint_offsets, base_pitch=0.0):
    """qpos of home plus joint offsets, base pitched forward, feet touching the floor."""
    qpos = m.key("home").qpos.copy()
    for name, dq in joint_offsets.items():
        qpos[m.jnt_qposadr[m.joint(name).id]] += dq
    qpos[3:7] = [np.cos(base_pitch / 2), 0.0, np.sin(base_pitch / 2), 0.0]
    qpos[2] = _stand_height(m, _all_feet(robot), qpos)
    return qpos


def _support_x(m, d, robot):
    """x range of the foot contact points and the whole-body COM x (world)."""
    xs = []
    for f in _all_feet(robot):
        g = m.geom(f)
        c = d.geom(f).xpos
        if g.type[0] == mujoco.mjtGeom.mjGEOM_CAPSULE:
            axis = d.geom(f).xmat.reshape(3, 3)[:, 2]
            xs += [c[0] + g.size[1] * axis[0], c[0] - g.size[1] * axis[0]]
        else:
            xs.append(c[0])
    return min(xs), max(xs), d.subtree_com[m.body("base").id][0]


# -------------------------------------------------------------------- tests
def test_total_mass(robot, model):
    assert float(model.body_mass.sum()) == pytest.approx(robot.total_mass, rel=0.03)


def test_lumped_base(robot, model):
    base = model.body("base")
    assert base.mass[0] == pytest.approx(robot.base_mass, rel=0.01)
    np.testing.assert_allclose(base.ipos, robot.base_com, atol=2e-3)


def test_inertials_explicit_and_geoms_massless(robot):
    spec = mujoco.MjSpec.from_file(str(ASSETS / robot.file))
    for body in spec.bodies:
        if body.name == "world":
            continue
        assert body.explicitinertial, f"{body.name}: no explicit <inertial>"
    for geom in spec.geoms:
        if geom.parent.name == "world":
            continue
        assert geom.density == 0, f"{geom.name}: density {geom.density}"
        assert np.isnan(geom.mass) or geom.mass == 0, f"{geom.name}: mass {geom.mass}"


def test_joint_structure(robot, model):
    n = len(robot.joints)
    assert model.body(1).name == "base"
    free = [i for i in range(model.njnt) if model.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE]
    assert len(free) == 1 and model.joint(free[0]).name == "root"
    assert model.jnt_bodyid[free[0]] == model.body("base").id
    hinges = [
        model.joint(i).name for i in range(model.njnt) if model.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE
    ]
    assert hinges == robot.joints
    assert model.njnt == 1 + n
    assert model.nq == 7 + n and model.nv == 6 + n
    assert np.all(model.jnt_limited[1:] == 1)
    assert np.all(model.dof_frictionloss == 0)
    assert model.neq == 0 and model.ntendon == 0
    site = model.site("imu")
    assert site.bodyid[0] == model.body("base").id
    np.testing.assert_allclose(site.pos, 0.0, atol=1e-9)
    # the knee bodies the biped env looks up; their origins are the knee joints
    knee = {"mit_humanoid.xml": "knee", "cassie.xml": "knee", "tron1.xml": "knee_joint"}[robot.file]
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    mujoco.mj_forward(model, d)
    for side in SIDES:
        body = model.body(f"{side}_knee_link")
        joint = model.joint(f"{side}_{knee}")
        assert model.jnt_bodyid[joint.id] == body.id
        np.testing.assert_allclose(d.xanchor[joint.id], d.xpos[body.id], atol=1e-9)


def test_actuators(robot, model):
    n = len(robot.joints)
    assert model.nu == n
    names = [model.actuator(i).name for i in range(model.nu)]
    assert names == robot.joints
    for i, jname in enumerate(robot.joints):
        assert model.actuator_trntype[i] == mujoco.mjtTrn.mjTRN_JOINT
        assert model.actuator_trnid[i, 0] == model.joint(jname).id
    check_motors(model, robot.torque)


def test_options(model):
    check_shared_options(model)
    assert model.nlight == 1


def test_joint_ranges(robot, model):
    for name in robot.joints:
        np.testing.assert_allclose(model.joint(name).range, robot.range_of(name), atol=1e-6, err_msg=name)


def test_axes_and_anchors_zero_pose(robot, model):
    d = mujoco.MjData(model)  # qpos0: base at its body pos, every joint at 0
    mujoco.mj_kinematics(model, d)
    base = d.xpos[model.body("base").id]
    for suffix, (left, right) in robot.axes.items():
        for side, ax in zip(SIDES, (left, right)):
            jid = model.joint(f"{side}_{suffix}").id
            np.testing.assert_allclose(d.xaxis[jid], ax, atol=1e-3, err_msg=f"{side}_{suffix}")
    for suffix, anchor in robot.anchors.items():
        for side, sy in zip(SIDES, (1, -1)):
            jid = model.joint(f"{side}_{suffix}").id
            expected = np.array(anchor) * [1, sy, 1]
            np.testing.assert_allclose(d.xanchor[jid] - base, expected, atol=1e-3, err_msg=f"{side}_{suffix}")


def test_home_keyframe_and_stand_height(robot, model):
    key = model.key("home")
    n = len(robot.joints)
    assert key.qpos.shape == (7 + n,)
    assert key.ctrl.shape == (n,)
    np.testing.assert_allclose(key.qpos[3:7], [1, 0, 0, 0])
    np.testing.assert_allclose(key.qpos[7:], robot.home, atol=1e-9)
    h = _stand_height(model, _all_feet(robot))
    assert h == pytest.approx(robot.stand_height, rel=0.05)
    # the home keyframe puts the feet on the floor (within 2 mm)
    assert key.qpos[2] == pytest.approx(h, abs=2e-3)
    # both feet touch: each side's lowest point is within 2 mm of the floor at home
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, key.id)
    mujoco.mj_forward(model, d)
    for side in SIDES:
        assert _lowest_foot_point(model, d, robot.feet[side]) == pytest.approx(0.0, abs=2e-3)


def test_only_feet_collide(robot, model):
    expected = {frozenset(("floor", f)) for f in _all_feet(robot)}
    assert colliding_pairs(model) == expected
    assert model.geom("floor").type[0] == mujoco.mjtGeom.mjGEOM_PLANE
    # feet are spheres or capsules (MJX plane-box keeps fewer contacts than MuJoCo C)
    for f in _all_feet(robot):
        assert int(model.geom(f).type[0]) in (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE))


def test_foot_sites(robot, model):
    """left_foot_site / right_foot_site sit at the sole centre of their foot."""
    d = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, d, model.key("home").id)
    mujoco.mj_forward(model, d)
    for side in SIDES:
        site = model.site(f"{side}_foot_site")
        feet = robot.feet[side]
        assert all(model.geom(f).bodyid[0] == site.bodyid[0] for f in feet)
        p = d.site(site.id).xpos
        centre = np.mean([d.geom(f).xpos for f in feet], axis=0)
        np.testing.assert_allclose(p[:2], centre[:2], atol=0.01)
        low = _lowest_foot_point(model, d, feet)
        assert -1e-9 <= p[2] - low < 0.005


def test_mjx_put_model(robot, model):
    from mujoco import mjx

    mx = mjx.put_model(model)
    assert mx.nu == len(robot.joints)


# ------------------------------------------------------- per-robot facts
def test_mit_foot_and_home_kinematics():
    m = _load(MIT)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_forward(m, d)
    base = d.xpos[m.body("base").id]
    for side, sy in zip(SIDES, (1, -1)):
        ankle = d.xanchor[m.joint(f"{side}_ankle").id]
        np.testing.assert_allclose(ankle - base, np.array(MIT_ANKLE_AT_HOME) * [1, sy, 1], atol=1e-3)
    # the four sole spheres span the URDF box sole: 0.17 x 0.05, 0.04 below the ankle
    d0 = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d0)
    for side in SIDES:
        ankle = d0.xanchor[m.joint(f"{side}_ankle").id]
        pts = np.array([d0.geom(f).xpos for f in MIT.feet[side]]) - ankle
        r = np.array([m.geom(f).size[0] for f in MIT.feet[side]])
        assert np.ptp(pts[:, 0]) == pytest.approx(MIT_FOOT_LENGTH, abs=1e-3)
        assert np.ptp(pts[:, 1]) == pytest.approx(MIT_FOOT_WIDTH, abs=1e-3)
        np.testing.assert_allclose(pts[:, 2] - r, -MIT_SOLE_DEPTH, atol=1e-6)


def test_cassie_foot_and_home_kinematics():
    m = _load(CASSIE)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_forward(m, d)
    base = d.xpos[m.body("base").id]
    for side, sy in zip(SIDES, (1, -1)):
        toe = d.xanchor[m.joint(f"{side}_toe").id]
        np.testing.assert_allclose(toe - base, np.array(CASSIE_TOE_AT_HOME) * [1, sy, 1], atol=1e-3)
        g = m.geom(f"{side}_foot")
        assert g.type[0] == mujoco.mjtGeom.mjGEOM_CAPSULE
        assert g.size[0] == pytest.approx(CASSIE_FOOT_RADIUS)
        # the foot lies nearly flat at the legged_gym default pose (DK: 0.855 stand height)
        axis = d.geom(g.id).xmat.reshape(3, 3)[:, 2]
        assert abs(axis[2]) < np.sin(np.radians(5))


def test_tron1_point_feet():
    m = _load(TRON1)
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    mujoco.mj_forward(m, d)
    for side in SIDES:
        g = m.geom(f"{side}_foot")
        assert g.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
        assert g.size[0] == pytest.approx(TRON1_FOOT_RADIUS)
        knee = d.xanchor[m.joint(f"{side}_knee_joint").id]
        np.testing.assert_allclose(d.geom(g.id).xpos - knee, TRON1_FOOT_FROM_KNEE, atol=5e-4)
        # site at the contact point, one radius below the sphere centre
        np.testing.assert_allclose(d.site(f"{side}_foot_site").xpos, d.geom(g.id).xpos - [0, 0, g.size[0]], atol=1e-9)


# --------------------------------------------------------------- PD holds
_PD_XFAIL = {
    "mit_humanoid": (
        "Physics, not a model bug (kinematics, COM and joint-space inertia match "
        "the URDF loaded in MuJoCo): at the PBRS default pose the whole-body COM "
        "is 44 mm behind the ankle axes and only 20 mm ahead of the heel edge, "
        "and the home feet are pitched 0.05 rad toe-down. With kp 30 the "
        "gravity stiffness of the ankle-knee-hip chain (about -156 N m/rad at "
        "the ankles, -92 at the knees) is not matched by 2 x 30 N m/rad; the "
        "knees sag (0.34 rad at 0.8 s) and the robot tips backwards from about "
        "0.6 s. The policy balances it. See test_pd_hold_stable_pose."
    ),
    "cassie": (
        "Physics, not a model bug (kinematics and joint-space inertia match the "
        "legged_gym URDF): the tarsus, passive on the real robot and held by the "
        "achilles rod, is here a kp 200 PD joint under a static load of about "
        "40 N m (half the weight on a 0.25 m lever); it sags 0.27 rad by 0.2 s. "
        "The toe (kp 40) is softer than the gravity "
        "stiffness about the feet (about -140 N m/rad against 2 x 40). The robot "
        "tips forward from about 0.9 s. The legged_gym policy balances it. See "
        "test_pd_hold_stable_pose."
    ),
    "tron1": (
        "Physics: point feet give no support area and no ankle, so the robot is "
        "an inverted pendulum about the line through the two contact points; "
        "the whole-body COM is 23 mm ahead of that line at home. Kp 42 also "
        "lets the knees sag (0.39 rad at 0.2 s under about 13 N m each). It "
        "tips forward from about 0.35 s. Only a policy can balance a "
        "point-footed biped."
    ),
}


@pytest.mark.parametrize(
    "name",
    [pytest.param(n, marks=pytest.mark.xfail(strict=True, reason=r)) for n, r in _PD_XFAIL.items()],
)
def test_pd_hold_reference_gains(name):
    robot = ROBOTS[name]
    finite, min_ratio, max_gz = pd_hold(_load(robot), robot.kp, robot.kd)
    assert finite
    assert min_ratio > 0.7
    assert max_gz < -0.9


# A statically stable pose, feet flat and COM over them, with stiff gains:
# the same thresholds must hold. This separates the falls above (reference
# pose and gains) from model bugs in mass, inertia or feet.
_STABLE = {
    # feet flat (ankle -0.05 undoes the toe-down tilt) and the whole robot
    # pitched 0.05 rad forward about the ankles, so the COM is mid-foot
    "mit_humanoid": (
        {"left_ankle": -0.10, "right_ankle": -0.10},
        0.05,
        [100, 100, 300, 300, 400] * 2,
        MIT_KD,
    ),
    # feet flat: toe -0.0497 undoes the 0.05 rad heel-down tilt of the default pose
    "cassie": (
        {"left_toe": -0.0497, "right_toe": -0.0497},
        0.0,
        [500, 500, 1000, 1000, 2000, 200] * 2,
        CASSIE_KD,
    ),
}


@pytest.mark.parametrize("name", list(_STABLE))
def test_pd_hold_stable_pose(name):
    robot = ROBOTS[name]
    m = _load(robot)
    offsets, pitch, kp, kd = _STABLE[name]
    qpos = _flat_pose(m, robot, offsets, pitch)
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    # precondition: both feet flat on the floor and the COM inside their x range
    for f in _all_feet(robot):
        assert _lowest_point(m, d, f) == pytest.approx(0.0, abs=1e-3)
    lo, hi, com_x = _support_x(m, d, robot)
    assert lo + 0.02 < com_x < hi - 0.02
    finite, min_ratio, max_gz = pd_hold(m, kp, kd, qpos=qpos)
    assert finite
    assert min_ratio > 0.7
    assert max_gz < -0.9


# ------------------------------------------------ comparison with the URDFs
# Source URDF (FACTS.md section 1), joint-name map (URDF -> ours) and the
# leg-link map (URDF link -> our body), left leg; "left"/"L" swap gives the right.
_URDF = {
    "mit_humanoid": (
        "mit_humanoid/pbrs_humanoid/mit_humanoid_fixed_arms.urdf",
        {f"{s}_{j}": f"{s}_{j}" for s in SIDES for j in _MIT_SUFFIX},
        {
            "left_hip_yaw": "left_hip_yaw_link",
            "left_hip_abad": "left_hip_abad_link",
            "left_upper_leg": "left_upper_leg_link",
            "left_lower_leg": "left_knee_link",
            "left_foot": "left_foot_link",
        },
    ),
    "cassie": (
        "cassie/legged_gym/cassie.urdf",
        {
            f"{u}_{s}": f"{s}_{o}"
            for s in SIDES
            for u, o in zip(
                ("hip_abduction", "hip_rotation", "hip_flexion", "thigh_joint", "ankle_joint", "toe_joint"),
                _CASSIE_SUFFIX,
            )
        },
        {
            "left_pelvis_rotation": "left_hip_roll_link",
            "left_hip": "left_hip_yaw_link",
            "left_thigh": "left_hip_pitch_link",
            "left_shin": "left_knee_link",
            "left_tarsus": "left_tarsus_link",
            "left_toe": "left_toe_link",
        },
    ),
    "tron1": (
        "tron1/robot_description/PF_TRON1A/urdf/robot.urdf",
        {f"{j}_{S}_Joint": f"{s}_{j}_joint" for s, S in zip(SIDES, "LR") for j in ("abad", "hip", "knee")},
        {"abad_L_Link": "left_abad_link", "hip_L_Link": "left_hip_link", "knee_L_Link": "left_knee_link"},
    ),
}


def _load_reference_urdf(relpath):
    """The source URDF in MuJoCo, with visuals, Gazebo blocks and comments removed.

    Only masses and COMs are compared here, so inertia tensors that MuJoCo
    rejects (the Cassie URDF base link is not positive definite; the MIT foot
    and Cassie toe break the triangle inequality with rotor inertia in one
    axis) are replaced by a small diagonal.
    """
    text = (REFERENCE_MODELS / relpath).read_text()
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    text = re.sub(r"<visual.*?</visual>", "", text, flags=re.S)
    text = re.sub(r"<gazebo.*?</gazebo>", "", text, flags=re.S)
    spec = mujoco.MjSpec.from_string(text)
    for body in spec.bodies:
        f = np.asarray(body.fullinertia, float)
        if not body.explicitinertial or np.isnan(f[0]):
            continue
        tensor = np.array([[f[0], f[3], f[4]], [f[3], f[1], f[5]], [f[4], f[5], f[2]]])
        ev = np.linalg.eigvalsh(tensor)
        if ev[0] <= 0 or ev[0] + ev[1] < ev[2]:
            body.fullinertia = [1e-6, 1e-6, 1e-6, 0.0, 0.0, 0.0]
    return spec.compile()


def _swap_side(name):
    return name.replace("left", "right").replace("_L_", "_R_")


@pytest.mark.skipif(not REFERENCE_MODELS.is_dir(), reason="shared/reference_models not present")
@pytest.mark.parametrize("name", list(_URDF))
def test_leg_masses_and_coms_match_source_urdf(name):
    """Per leg link: mass, and the COM of every leg subtree at a bent pose."""
    robot = ROBOTS[name]
    relpath, joint_map, link_map = _URDF[name]
    ref, m = _load_reference_urdf(relpath), _load(robot)
    dr, dm = mujoco.MjData(ref), mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, dm, m.key("home").id)
    # a pose away from home on every joint, inside every range
    rng = np.random.default_rng(0)
    for urdf_joint, ours in joint_map.items():
        lo, hi = m.joint(ours).range
        q = lo + (hi - lo) * rng.uniform(0.3, 0.7) if hi - lo < 6 else rng.uniform(-0.5, 0.5)
        dm.qpos[m.jnt_qposadr[m.joint(ours).id]] = q
        dr.qpos[ref.jnt_qposadr[ref.joint(urdf_joint).id]] = q
    dm.qpos[:3] = 0.0  # the URDF root sits at the world origin
    mujoco.mj_forward(ref, dr)
    mujoco.mj_forward(m, dm)
    for left_link, left_body in link_map.items():
        for link, body in ((left_link, left_body), (_swap_side(left_link), _swap_side(left_body))):
            bid, rid = m.body(body).id, ref.body(link).id
            assert m.body_subtreemass[bid] == pytest.approx(ref.body_subtreemass[rid], abs=1e-3), body
            np.testing.assert_allclose(dm.subtree_com[bid], dr.subtree_com[rid], atol=1e-3, err_msg=body)
            np.testing.assert_allclose(dm.xpos[bid], dr.xpos[rid], atol=1e-4, err_msg=body)

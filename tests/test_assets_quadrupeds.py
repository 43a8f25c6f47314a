"""Fact checks for the simplified quadruped MJCF models assets/{a1,anymal_b,anymal_c}.xml.

Reference numbers come from /work/shared/reference_models/FACTS.md (section 3 "Unitree A1",
section 4 "ANYmal B", section 5 "ANYmal C") and DERIVED_KINEMATICS.md ("DK"). ANYmal's legs
LF, RF, LH, RH are FL, FR, RL, RR in the models, and its joints HAA, HFE, KFE are hip, thigh
and calf; the DK anchors below are given under our names, with the original name in a comment.
Everything runs on the MuJoCo C library except the mjx.put_model check (no jit, no stepping).
"""

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
import pytest
from mjcf_checks import check_motors, check_shared_options, colliding_pairs, hinge_names, pd_hold

ASSETS = Path(__file__).resolve().parents[1] / "assets"

LEGS = ("FL", "FR", "RL", "RR")
JOINTS = [f"{leg}_{part}_joint" for leg in LEGS for part in ("hip", "thigh", "calf")]
FEET = [f"{leg}_foot" for leg in LEGS]

# ------------------------------------------------------------------ A1 facts
# FACTS.md section 3: total 12.453 kg; trunk 4.713; per leg 1.935 (hip 0.696 + thigh 1.013
# + calf 0.226 including the 0.06 foot).
A1_TOTAL_MASS = 12.453
A1_BASE_MASS = 4.713
A1_LEG_MASS = 1.935
# FACTS.md section 3: legged_gym default angles, hip +-0.1 (FL/RL +), thigh 0.8 front /
# 1.0 rear, calf -1.5; geometric height ~0.30 (DK legged_gym a1.urdf table: 0.302).
A1_HOME = [0.1, 0.8, -1.5, -0.1, 0.8, -1.5, 0.1, 1.0, -1.5, -0.1, 1.0, -1.5]
A1_STAND_HEIGHT = 0.302
# DK (A1, zero pose): lowest collision point 0.420 below the trunk origin.
A1_ZERO_POSE_HEIGHT = 0.420
# FACTS.md section 3 / section 10: foot sphere r 0.02.
A1_FOOT_RADIUS = 0.02
# FACTS.md section 3: 33.5 N m on every joint (A1 spec, menagerie); URDF 20/55/55 not used.
A1_TORQUE = [33.5] * 12
# FACTS.md section 3: abduction +-0.802851; thigh [-1.0472, 4.18879]; calf [-2.69653, -0.916298].
A1_RANGES = {"hip": (-0.802851, 0.802851), "thigh": (-1.0472, 4.18879), "calf": (-2.69653, -0.916298)}
# FACTS.md section 3: legged_gym a1_config kp 20, kd 0.5.
A1_KP, A1_KD = 20.0, 0.5
# DK (A1): anchors in the trunk frame, zero pose and legged_gym default pose.
A1_ZERO_ANCHORS = {
    "FL_hip_joint": (0.183, 0.047, 0.0),
    "FL_thigh_joint": (0.183, 0.1321, 0.0),
    "FL_calf_joint": (0.183, 0.1321, -0.2),
    "RR_calf_joint": (-0.183, -0.1321, -0.2),
}
A1_HOME_ANCHORS = {
    "FR_calf_joint": (0.0395, -0.1455, -0.1302),
    "FL_calf_joint": (0.0395, 0.1455, -0.1302),
    "RR_calf_joint": (-0.3513, -0.1424, -0.0990),
    "RL_calf_joint": (-0.3513, 0.1424, -0.0990),
}

# ------------------------------------------------------------- ANYmal B facts
# FACTS.md section 4: legged_gym URDF total 30.62 kg, base 16.79, per leg 3.457
# (menagerie 33.33 / 19.20 is not used; see the model header).
ANYMAL_B_TOTAL_MASS = 30.62
ANYMAL_B_BASE_MASS = 16.79
ANYMAL_B_LEG_MASS = 3.457
# FACTS.md section 4: default angles HAA 0; HFE +0.4 front / -0.4 hind; KFE -0.8 front /
# +0.8 hind; stand height 0.497.
ANYMAL_HOME = [0.0, 0.4, -0.8, 0.0, 0.4, -0.8, 0.0, -0.4, 0.8, 0.0, -0.4, 0.8]
ANYMAL_B_STAND_HEIGHT = 0.497
# DK (ANYmal B, zero pose): lowest collision point 0.579 below the base origin.
ANYMAL_B_ZERO_POSE_HEIGHT = 0.579
# FACTS.md section 4 / section 10: foot sphere r 0.031.
ANYMAL_B_FOOT_RADIUS = 0.031
# FACTS.md section 4: ANYdrive 40 N m (menagerie forcerange); URDF effort 80 not used.
ANYMAL_B_TORQUE = [40.0] * 12
# FACTS.md section 4: URDF limits +-9.42 on every joint (menagerie has none).
ANYMAL_B_RANGES = {"hip": (-9.42, 9.42), "thigh": (-9.42, 9.42), "calf": (-9.42, 9.42)}
# DK (ANYmal B): anchors in the base frame.
ANYMAL_B_ZERO_ANCHORS = {
    "FL_hip_joint": (0.277, 0.116, 0.0),  # LF_HAA
    "FL_thigh_joint": (0.3405, 0.157, 0.0),  # LF_HFE
    "FL_calf_joint": (0.3405, 0.266, -0.25),  # LF_KFE
    "RR_calf_joint": (-0.3405, -0.266, -0.25),  # RH_KFE
}
ANYMAL_B_HOME_ANCHORS = {
    "FL_calf_joint": (0.2431, 0.2660, -0.2303),  # LF_KFE
    "FR_calf_joint": (0.2431, -0.2660, -0.2303),  # RF_KFE
    "RL_calf_joint": (-0.2431, 0.2660, -0.2303),  # LH_KFE
    "RR_calf_joint": (-0.2431, -0.2660, -0.2303),  # RH_KFE
}

# ------------------------------------------------------------- ANYmal C facts
# FACTS.md section 5: legged_gym URDF total 52.13 kg; torso 26.37 including the four HAA
# drives; per leg 6.44 (menagerie 44.97 copies ANYmal B's base; see the model header).
ANYMAL_C_TOTAL_MASS = 52.13
ANYMAL_C_BASE_MASS = 26.37
ANYMAL_C_LEG_MASS = 6.44
# FACTS.md section 5: legged_gym default angles (same as B) -> stand height 0.549.
ANYMAL_C_STAND_HEIGHT = 0.549
# DK (ANYmal C, zero pose): lowest collision point 0.6305 below the base origin.
ANYMAL_C_ZERO_POSE_HEIGHT = 0.6305
# FACTS.md section 5 / section 10: foot sphere r 0.03.
ANYMAL_C_FOOT_RADIUS = 0.03
# FACTS.md section 5: 80 N m (menagerie forcerange and URDF effort).
ANYMAL_C_TORQUE = [80.0] * 12
# FACTS.md section 5 (menagerie): HAA LF/LH [-0.72, 0.49], RF/RH [-0.49, 0.72]; HFE, KFE +-9.42478.
ANYMAL_C_RANGES = {
    "hip_left": (-0.72, 0.49),
    "hip_right": (-0.49, 0.72),
    "thigh": (-9.42478, 9.42478),
    "calf": (-9.42478, 9.42478),
}
# DK (ANYmal C): anchors in the base frame.
ANYMAL_C_ZERO_ANCHORS = {
    "FL_hip_joint": (0.2999, 0.104, 0.0),  # LF_HAA
    "FL_thigh_joint": (0.3598, 0.1878, 0.0),  # LF_HFE
    "FL_calf_joint": (0.3598, 0.2881, -0.285),  # LF_KFE
    "RR_calf_joint": (-0.3598, -0.2881, -0.285),  # RH_KFE
}
ANYMAL_C_HOME_ANCHORS = {
    "FL_calf_joint": (0.2488, 0.2881, -0.2625),  # LF_KFE
    "FR_calf_joint": (0.2488, -0.2881, -0.2625),  # RF_KFE
    "RL_calf_joint": (-0.2488, 0.2881, -0.2625),  # LH_KFE
    "RR_calf_joint": (-0.2488, -0.2881, -0.2625),  # RH_KFE
}
# FACTS.md sections 4 and 5: legged_gym kp 80, kd 2 (all joints) for both ANYmals.
ANYMAL_KP, ANYMAL_KD = 80.0, 2.0


@dataclass(frozen=True)
class Robot:
    file: str
    total_mass: float
    base_mass: float
    leg_mass: float
    home: list
    stand_height: float
    zero_pose_height: float
    foot_radius: float
    torque: list
    ranges: dict
    kp: float
    kd: float
    zero_anchors: dict
    home_anchors: dict

    def joint_range(self, name):
        leg, part = name.split("_")[:2]
        if part == "hip" and "hip_left" in self.ranges:
            return self.ranges["hip_left" if leg[1] == "L" else "hip_right"]
        return self.ranges[part]


ROBOTS = {
    "a1": Robot(
        "a1.xml", A1_TOTAL_MASS, A1_BASE_MASS, A1_LEG_MASS, A1_HOME, A1_STAND_HEIGHT,
        A1_ZERO_POSE_HEIGHT, A1_FOOT_RADIUS, A1_TORQUE, A1_RANGES, A1_KP, A1_KD,
        A1_ZERO_ANCHORS, A1_HOME_ANCHORS,
    ),
    "anymal_b": Robot(
        "anymal_b.xml", ANYMAL_B_TOTAL_MASS, ANYMAL_B_BASE_MASS, ANYMAL_B_LEG_MASS, ANYMAL_HOME,
        ANYMAL_B_STAND_HEIGHT, ANYMAL_B_ZERO_POSE_HEIGHT, ANYMAL_B_FOOT_RADIUS, ANYMAL_B_TORQUE,
        ANYMAL_B_RANGES, ANYMAL_KP, ANYMAL_KD, ANYMAL_B_ZERO_ANCHORS, ANYMAL_B_HOME_ANCHORS,
    ),
    "anymal_c": Robot(
        "anymal_c.xml", ANYMAL_C_TOTAL_MASS, ANYMAL_C_BASE_MASS, ANYMAL_C_LEG_MASS, ANYMAL_HOME,
        ANYMAL_C_STAND_HEIGHT, ANYMAL_C_ZERO_POSE_HEIGHT, ANYMAL_C_FOOT_RADIUS, ANYMAL_C_TORQUE,
        ANYMAL_C_RANGES, ANYMAL_KP, ANYMAL_KD, ANYMAL_C_ZERO_ANCHORS, ANYMAL_C_HOME_ANCHORS,
    ),
}


# ------------------------------------------------------------------ helpers
@pytest.fixture(params=list(ROBOTS), scope="module")
def robot(request):
    return request.param, ROBOTS[request.param]


@pytest.fixture(scope="module")
def model(robot):
    _, spec = robot
    return mujoco.MjModel.from_xml_path(str(ASSETS / spec.file))


def _data_at(m, qpos_joints=None, base_z=None):
    """MjData after mj_forward: the home keyframe, or qpos0 with the given joint angles
    (level base at x = y = 0 either way), optionally at another base height."""
    d = mujoco.MjData(m)
    if qpos_joints is None:
        mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    else:
        d.qpos[7:] = qpos_joints
    if base_z is not None:
        d.qpos[2] = base_z
    mujoco.mj_forward(m, d)
    return d


def _lowest_foot_point(m, d):
    """World z of the lowest point of the four foot spheres."""
    return min(d.geom(f).xpos[2] - m.geom(f).size[0] for f in FEET)


def _stand_height(m, qpos_joints=None):
    """Base height with a level base at which the lowest foot just touches the floor."""
    d = _data_at(m, qpos_joints, base_z=2.0)  # well above the floor, nothing touches
    return d.qpos[2] - _lowest_foot_point(m, d)


# -------------------------------------------------------------------- tests
def test_total_and_body_masses(robot, model):
    _, spec = robot
    assert float(model.body_mass.sum()) == pytest.approx(spec.total_mass, rel=0.03)
    assert model.body("base").mass[0] == pytest.approx(spec.base_mass, rel=0.01)
    for leg in LEGS:
        leg_mass = sum(model.body(f"{leg}_{p}").mass[0] for p in ("hip", "thigh", "calf"))
        assert leg_mass == pytest.approx(spec.leg_mass, rel=0.01)
    # every body has a real inertia (positive principal moments satisfying the triangle rule)
    for b in range(1, model.nbody):
        i = np.sort(model.body_inertia[b])
        assert i[0] > 0 and i[0] + i[1] >= i[2] * (1 - 1e-9)


def test_explicit_inertials_and_massless_geoms(robot):
    _, spec = robot
    s = mujoco.MjSpec.from_file(str(ASSETS / spec.file))
    for body in s.bodies:
        if body.name != "world":
            assert body.explicitinertial, body.name
    for geom in s.geoms:
        if geom.parent.name != "world":
            assert geom.density == 0, geom.name
    primitives = {
        mujoco.mjtGeom.mjGEOM_CAPSULE,
        mujoco.mjtGeom.mjGEOM_BOX,
        mujoco.mjtGeom.mjGEOM_SPHERE,
        mujoco.mjtGeom.mjGEOM_CYLINDER,
        mujoco.mjtGeom.mjGEOM_PLANE,  # the floor only
    }
    assert all(s.geoms[i].type in primitives for i in range(len(s.geoms)))


def test_joint_structure(model):
    assert model.body(1).name == "base"
    free = [i for i in range(model.njnt) if model.jnt_type[i] == mujoco.mjtJoint.mjJNT_FREE]
    assert len(free) == 1 and model.joint(free[0]).name == "root"
    assert model.jnt_bodyid[free[0]] == model.body("base").id
    assert hinge_names(model) == JOINTS
    assert model.nq == 7 + 12 and model.nv == 6 + 12
    assert np.all(model.jnt_limited[1:] == 1)
    assert np.all(model.dof_frictionloss == 0)
    site = model.site("imu")
    assert site.bodyid[0] == model.body("base").id
    np.testing.assert_allclose(site.pos, 0.0, atol=1e-9)


def test_joint_ranges(robot, model):
    _, spec = robot
    for name in JOINTS:
        np.testing.assert_allclose(model.joint(name).range, spec.joint_range(name), atol=1e-6)


def test_actuators(robot, model):
    _, spec = robot
    assert model.nu == 12
    assert [model.actuator(i).name for i in range(model.nu)] == JOINTS
    for i, jname in enumerate(JOINTS):
        assert model.actuator_trnid[i, 0] == model.joint(jname).id
    check_motors(model, spec.torque)


def test_options(model):
    check_shared_options(model)


def test_axes_and_zero_pose_kinematics(robot, model):
    _, spec = robot
    d = _data_at(model, qpos_joints=np.zeros(12), base_z=0.0)
    for leg in LEGS:  # FACTS: hip/HAA +x, thigh/HFE and calf/KFE +y on every leg
        np.testing.assert_allclose(d.xaxis[model.joint(f"{leg}_hip_joint").id], [1, 0, 0], atol=1e-9)
        np.testing.assert_allclose(d.xaxis[model.joint(f"{leg}_thigh_joint").id], [0, 1, 0], atol=1e-9)
        np.testing.assert_allclose(d.xaxis[model.joint(f"{leg}_calf_joint").id], [0, 1, 0], atol=1e-9)
    for jname, anchor in spec.zero_anchors.items():
        np.testing.assert_allclose(d.xanchor[model.joint(jname).id], anchor, atol=1e-4)
    # DK: legs straight, the lowest foot point is this far below the base origin
    assert -_lowest_foot_point(model, d) == pytest.approx(spec.zero_pose_height, abs=1e-3)


def test_home_keyframe_and_feet(robot, model):
    _, spec = robot
    key = model.key("home")
    assert key.qpos.shape == (model.nq,) and key.qpos.shape == (19,)
    np.testing.assert_allclose(key.qpos[3:7], [1, 0, 0, 0])
    np.testing.assert_allclose(key.qpos[7:], spec.home, atol=1e-9)
    np.testing.assert_allclose(key.ctrl, 0.0)
    d = _data_at(model)
    base = d.xpos[model.body("base").id]
    for foot in FEET:
        g = model.geom(foot)
        assert g.type[0] == mujoco.mjtGeom.mjGEOM_SPHERE
        assert g.size[0] == pytest.approx(spec.foot_radius)
        np.testing.assert_allclose(d.site(f"{foot}_site").xpos, d.geom(foot).xpos, atol=1e-9)
    # DK: knee (calf joint) anchors at the default pose, which also fixes the knee direction
    for jname, anchor in spec.home_anchors.items():
        np.testing.assert_allclose(d.xanchor[model.joint(jname).id] - base, anchor, atol=1e-3)


@pytest.mark.parametrize("name", ["anymal_b", "anymal_c"])
def test_anymal_knees_point_inwards(name):
    # FACTS.md sections 4, 5 and note 10.3: the real ANYmal kinematics at the default pose
    m = mujoco.MjModel.from_xml_path(str(ASSETS / ROBOTS[name].file))
    d = _data_at(m)
    for leg in LEGS:
        knee_x = d.xanchor[m.joint(f"{leg}_calf_joint").id][0]
        hip_x = d.xanchor[m.joint(f"{leg}_thigh_joint").id][0]
        if leg[0] == "F":
            assert knee_x < hip_x  # front knees point backwards
        else:
            assert knee_x > hip_x  # hind knees point forwards


def test_stand_height(robot, model):
    _, spec = robot
    # geometric stand height at the reference pose: level base, lowest foot on the floor
    h = _stand_height(model, np.asarray(spec.home))
    assert h == pytest.approx(spec.stand_height, rel=0.05)
    # the home keyframe puts the base at that height (within 2 mm)
    assert model.key("home").qpos[2] == pytest.approx(h, abs=2e-3)


def test_only_feet_collide(model):
    expected = {frozenset(("floor", f)) for f in FEET}
    assert colliding_pairs(model) == expected
    assert model.npair == 0
    assert model.geom("floor").type[0] == mujoco.mjtGeom.mjGEOM_PLANE
    assert model.geom("floor").contype[0] == 1 and model.geom("floor").conaffinity[0] == 0
    for foot in FEET:
        assert model.geom(foot).contype[0] == 0 and model.geom(foot).conaffinity[0] == 1
    others = [i for i in range(model.ngeom) if model.geom(i).name not in FEET + ["floor"]]
    assert np.all(model.geom_contype[others] == 0) and np.all(model.geom_conaffinity[others] == 0)
    assert model.nlight == 1


def testpd_hold(robot, model):
    _, spec = robot
    finite, min_ratio, max_gz = pd_hold(model, spec.kp, spec.kd)
    assert finite
    assert min_ratio > 0.7
    assert max_gz < -0.9


def test_mjx_put_model(model):
    from mujoco import mjx

    mx = mjx.put_model(model)
    assert mx.nu == 12

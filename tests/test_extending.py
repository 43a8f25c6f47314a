"""docs/extending.md followed for a ninth robot: a toy quadruped written from the guide's rules
(free joint first, a motor per hinge, a ``home`` keyframe, foot-only collisions, ``<LEG>_foot_site``
sites, joint roles), registered with one entry, passes the registry walk's checks: sizes,
finite values, the logged terms, a 2 s hold of its home pose, and the semantic map from Go2."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import registry
from envs.quadruped import GO2_CONFIG, QUADRUPED_ROLES, QuadrupedEnv

LEGS = {"FL": (0.19, 0.06), "FR": (0.19, -0.06), "RL": (-0.19, 0.06), "RR": (-0.19, -0.06)}
HOME_JOINTS = (0.0, 0.8, -1.5)  # hip roll, hip pitch, knee


def toy_quadruped_xml() -> str:
    """A 6.6 kg box-and-capsule quadruped, 12 hinges, in the shape docs/extending.md asks for."""
    legs = []
    for leg, (x, y) in LEGS.items():
        legs.append(f"""
      <body name="{leg}_hip" pos="{x} {y} 0">
        <joint name="{leg}_hip_joint" axis="1 0 0" range="-0.8 0.8"/>
        <geom type="sphere" size="0.03" mass="0.3" contype="0" conaffinity="0"/>
        <body name="{leg}_thigh">
          <joint name="{leg}_thigh_joint" axis="0 1 0" range="-1.5 3.0"/>
          <geom type="capsule" fromto="0 0 0 0 0 -0.15" size="0.015" mass="0.5" contype="0" conaffinity="0"/>
          <body name="{leg}_calf" pos="0 0 -0.15">
            <joint name="{leg}_calf_joint" axis="0 1 0" range="-2.7 -0.8"/>
            <geom type="capsule" fromto="0 0 0 0 0 -0.15" size="0.012" mass="0.2" contype="0" conaffinity="0"/>
            <geom name="{leg}_foot" type="sphere" pos="0 0 -0.15" size="0.02" mass="0.05" friction="0.8 0.02 0.01"/>
            <site name="{leg}_foot_site" pos="0 0 -0.15" size="0.01"/>
          </body>
        </body>
      </body>""")
    motors = "".join(f'\n    <motor name="{leg}_{j}" joint="{leg}_{j}_joint" ctrlrange="-25 25"/>'
                     for leg in LEGS for j in ("hip", "thigh", "calf"))
    qpos = " ".join(["0 0 0.24 1 0 0 0"] + [" ".join(map(str, HOME_JOINTS))] * 4)
    return f"""<mujoco model="toy_quadruped">
  <option timestep="0.01"/>
  <default><joint damping="0.5" armature="0.01"/></default>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.05" friction="1 0.005 0.0001"/>
    <body name="base" pos="0 0 0.24">
      <freejoint name="root"/>
      <geom type="box" size="0.2 0.08 0.04" mass="5.0" contype="0" conaffinity="0"/>{''.join(legs)}
    </body>
  </worldbody>
  <actuator>{motors}
  </actuator>
  <keyframe><key name="home" qpos="{qpos}"/></keyframe>
</mujoco>
"""


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    path = tmp_path_factory.mktemp("assets") / "toy_quadruped.xml"
    path.write_text(toy_quadruped_xml())
    # An absolute asset path is read as is. MuJoCo C's engine: the walk's checks are the same, and
    # its compile is a fraction of MJX's (the eight robots' MJX walk is tests/test_envs.py).
    config = dataclasses.replace(GO2_CONFIG, asset=str(path), joint_roles=QUADRUPED_ROLES, engine="mujoco")
    entry = registry.RobotEntry(QuadrupedEnv, config, "toy quadruped, 12 DOF (docs/extending.md)")
    registry.ROBOTS["toy_quadruped"] = entry
    try:
        yield envs.make("toy_quadruped")
    finally:
        del registry.ROBOTS["toy_quadruped"]


@pytest.mark.xdist_group("toy_robot")
class TestANinthRobotFromTheGuide:
    def test_registry_walk(self, toy):
        from test_envs import reset_and_hold

        assert "toy_quadruped" in envs.robot_names()
        keys = jax.random.split(jax.random.PRNGKey(0), 4)
        first, last, (done, height, finite, _, _) = reset_and_hold(toy, keys, int(round(2.0 / toy.config.ctrl_dt)))
        assert first.obs["state"].shape == (4, 45)
        assert np.all(np.asarray(finite))
        assert set(last.metrics) == {f"reward/{k}" for k in dataclasses.asdict(toy.config.rewards)}
        assert not np.any(np.asarray(done)), "the toy fell within 2 s of holding its home pose"
        assert float(np.min(height)) > toy.config.termination_height

    def test_the_semantic_map_from_go2_is_the_identity(self, toy):
        from ptrl_jax.core import semantic

        m = semantic.build_map(envs.make("go2"), toy)
        assert np.array_equal(m.joint_source, np.arange(12)) and np.all(np.abs(m.joint_factor) > 0)
        assert np.array_equal(np.sign(m.joint_factor), np.ones(12))
        assert jnp.asarray(toy.joint_signs).shape == (12,)

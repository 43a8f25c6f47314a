"""MuJoCo C helpers shared by the model fact tests (tests/test_assets*.py)."""

import mujoco
import numpy as np


def hinge_names(m: mujoco.MjModel) -> list[str]:
    return [m.joint(i).name for i in range(m.njnt) if m.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE]


def colliding_pairs(m: mujoco.MjModel) -> set[frozenset]:
    """Geom pairs allowed to collide by contype/conaffinity (plus explicit pairs)."""
    pairs = set()
    for i in range(m.ngeom):
        for j in range(i + 1, m.ngeom):
            if m.geom_bodyid[i] == m.geom_bodyid[j]:
                continue
            if (m.geom_contype[i] & m.geom_conaffinity[j]) or (m.geom_contype[j] & m.geom_conaffinity[i]):
                pairs.add(frozenset((m.geom(i).name, m.geom(j).name)))
    for k in range(m.npair):
        pairs.add(frozenset((m.geom(m.pair_geom1[k]).name, m.geom(m.pair_geom2[k]).name)))
    return pairs


def pd_hold(m: mujoco.MjModel, kp, kd, qpos=None, seconds: float = 2.0) -> tuple[bool, float, float]:
    """Hold a pose with tau = kp (q* - q) - kd qdot, clipped to ctrlrange.

    The pose is the home keyframe, or ``qpos`` (then also the PD target).
    Returns (finite, min base height / initial height, max projected-gravity z).
    """
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, m.key("home").id)
    if qpos is not None:
        d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    q_star = d.qpos[7:].copy()
    z0 = d.qpos[2]
    kp = np.broadcast_to(np.asarray(kp, float), q_star.shape)
    kd = np.broadcast_to(np.asarray(kd, float), q_star.shape)
    lo, hi = m.actuator_ctrlrange.T
    base = m.body("base").id
    min_ratio, max_gz = np.inf, -np.inf
    for _ in range(int(round(seconds / m.opt.timestep))):
        tau = kp * (q_star - d.qpos[7:]) - kd * d.qvel[6:]
        d.ctrl[:] = np.clip(tau, lo, hi)
        mujoco.mj_step(m, d)
        if not (np.all(np.isfinite(d.qpos)) and np.all(np.isfinite(d.qvel))):
            return False, min_ratio, max_gz
        gz = -d.xmat[base].reshape(3, 3)[2, 2]  # gravity in the base frame, z component
        min_ratio = min(min_ratio, d.qpos[2] / z0)
        max_gz = max(max_gz, gz)
    return True, min_ratio, max_gz


def check_motors(m: mujoco.MjModel, torque) -> None:
    """Plain torque motors: gear 1, unit gain, no bias, ctrlrange +- the torque limits."""
    np.testing.assert_allclose(m.actuator_gear[:, 0], 1.0)
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], 1.0)
    assert np.all(m.actuator_biastype == mujoco.mjtBias.mjBIAS_NONE)
    assert np.all(m.actuator_ctrllimited == 1)
    lim = np.asarray(torque, float)
    np.testing.assert_allclose(m.actuator_ctrlrange, np.stack([-lim, lim], 1))


def check_shared_options(m: mujoco.MjModel) -> None:
    """The <option> line every asset shares (the env overrides step and solver at load)."""
    assert m.opt.timestep == 0.005
    assert m.opt.iterations == 2 and m.opt.ls_iterations == 6
    assert m.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_EULER
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EULERDAMP

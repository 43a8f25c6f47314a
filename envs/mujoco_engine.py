"""``engine=mujoco``: physics substeps in MuJoCo C's thread pool, called from inside the jitted
program through a JAX host callback.

Only the integration leaves JAX. The env's own code (PD law, domain randomization draws,
observation, reward, termination, resets, commands) is the same for both engines: it computes
the substep's torques in JAX and hands them, with the state, to ``step``, which writes them into
a ``mujoco.batch.Batch`` (one simulation per env, variant and seed: the callback receives every
vmapped axis at once and flattens them), runs one ``mj_step`` per simulation on the batch's
threads, and returns the new state and the derived fields the env reads (site and body
positions). As with ``mjx.step``, those describe the state before the substep's integration.

The physics state (qpos, qvel and the solver's warm start) lives in the env state, in JAX, as
float32: the program stays functional, so vmap, checkpoints, bitwise resume and same-seed
determinism hold as with MJX (the batch's results do not depend on its thread count). The price
is that MuJoCo C integrates from float32-rounded states each substep, where a MuJoCo C program
of its own would keep float64.

Domain randomization's model fields (friction, base mass, joint damping) are written per
simulation with ``Batch.expand`` before each call.
"""

from __future__ import annotations

import os
import threading
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import batch as mj_batch

ENGINES = ("mjx", "mujoco")
"""Physics engines of the envs: MJX (JAX, GPU or CPU) and MuJoCo C (CPU threads)."""

AUTO = "auto"
"""An experiment's default engine: MuJoCo C where jax runs on the CPU, MJX on an accelerator
(``resolve_engine``). Measured on 2 CPU cores, MuJoCo C trained Go2 1.36 times faster and
compiled its trainer 2.3 times faster (BENCHMARKS.md, 2026-12-02)."""

ENGINE_CHOICES = (*ENGINES, AUTO)
"""What an experiment's ``engine`` may name."""


def resolve_engine(name: str) -> str:
    """The engine ``name`` stands for on this machine: ``auto`` is ``mujoco`` when jax's default
    backend is the CPU and ``mjx`` otherwise; ``mjx`` and ``mujoco`` are themselves."""
    if name == AUTO:
        return "mujoco" if jax.default_backend() == "cpu" else "mjx"
    if name not in ENGINES:
        raise ValueError(f"engine must be one of {list(ENGINE_CHOICES)}, got {name!r}")
    return name

_OUT_FIELDS = ("qpos", "qvel", "qacc_warmstart", "site_xpos", "xpos")


class MujocoStepper:
    """One robot model's MuJoCo C stepper: a ``Batch`` per simulation count, made on first use."""

    def __init__(self, model: mujoco.MjModel, base_body: int, nthread: int | None = None):
        self.model = model
        self.base_body = base_body
        self.nthread = nthread or int(os.environ.get("PTRL_MUJOCO_THREADS", 0)) or os.cpu_count() or 1
        self._batches: dict[int, mj_batch.Batch] = {}
        self._lock = threading.Lock()

    def _batch(self, n: int) -> mj_batch.Batch:
        b = self._batches.get(n)
        if b is None:
            b = mj_batch.Batch(self.model, n, self.nthread)
            self._batches[n] = b
        return b

    # ----- the host side ----------------------------------------------------------------------
    def _host_step(self, qpos, qvel, warm, ctrl, friction, base_mass, damping_scale):
        lead = qpos.shape[:-1]
        n = int(np.prod(lead)) if lead else 1
        m = self.model
        with self._lock:  # a Batch is not to be used from several threads at once
            b = self._batch(n)
            b.bind("qpos")[:] = np.asarray(qpos, np.float64).reshape(n, m.nq)
            b.bind("qvel")[:] = np.asarray(qvel, np.float64).reshape(n, m.nv)
            b.bind("qacc_warmstart")[:] = np.asarray(warm, np.float64).reshape(n, m.nv)
            b.bind("ctrl")[:] = np.asarray(ctrl, np.float64).reshape(n, m.nu)
            if friction is not None:
                f = b.expand("geom_friction")
                f[:, :, 0] = np.asarray(friction, np.float64).reshape(n, 1)
                mass = b.expand("body_mass")
                mass[:] = m.body_mass
                mass[:, self.base_body] += np.asarray(base_mass, np.float64).reshape(n)
                damping = b.expand("dof_damping")
                damping[:] = m.dof_damping
                damping[:, 6:] *= np.asarray(damping_scale, np.float64).reshape(n, 1)
            b.step()
            return tuple(np.asarray(b.bind(k), np.float32).reshape(lead + b.bind(k).shape[1:])
                         for k in _OUT_FIELDS)

    # ----- the JAX side -------------------------------------------------------------------------
    def step(self, data: Any, draw: dict | None = None) -> Any:
        """One physics substep of ``data`` (an ``mjx.Data`` used as the state's container) with
        its ``ctrl``; ``draw``: the episode's domain randomization draw, or None."""
        m = self.model
        shapes = (
            jax.ShapeDtypeStruct((m.nq,), jnp.float32), jax.ShapeDtypeStruct((m.nv,), jnp.float32),
            jax.ShapeDtypeStruct((m.nv,), jnp.float32), jax.ShapeDtypeStruct((m.nsite, 3), jnp.float32),
            jax.ShapeDtypeStruct((m.nbody, 3), jnp.float32),
        )
        f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
        if draw is None:
            callback = lambda q, v, w, c: self._host_step(q, v, w, c, None, None, None)  # noqa: E731
            args = (f32(data.qpos), f32(data.qvel), f32(data.qacc_warmstart), f32(data.ctrl))
        else:
            callback = self._host_step
            args = (f32(data.qpos), f32(data.qvel), f32(data.qacc_warmstart), f32(data.ctrl),
                    f32(draw["friction"]), f32(draw["added_base_mass"]), f32(draw["kd_scale"]))
        qpos, qvel, warm, site_xpos, xpos = jax.pure_callback(callback, shapes, *args, vmap_method="broadcast_all")
        return data.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm, site_xpos=site_xpos, xpos=xpos)

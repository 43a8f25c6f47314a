"""The PTRL program over several local devices (issue 22): the env batch laid out across a
one-axis ``jax.sharding.Mesh``, everything else replicated, and XLA's SPMD partitioner doing the
rest.

The program is written for one device (``program.py``, ``train.py``): it vmaps over variants,
seeds and envs, and PPO's losses, gradients, normaliser statistics and episode metrics are means
over the whole env batch. Running it under ``jit`` with the env axis of the env states and
episode accumulators sharded over the ``envs`` mesh axis keeps those semantics exactly: the
partitioner inserts the all-reduces (gradient and statistic means) and the gathers (minibatch
shuffles across envs) that the global view implies, so a run on N devices equals the one-device
run up to the order of float reductions. With ``engine=mujoco`` the physics callback receives
the whole batch (a host callback is not partitioned) and MuJoCo C spreads it over its threads.

``devices=all|N`` picks the devices (``resolve_devices``); every stage's env count must divide
by N, checked before anything compiles (``check_divisible``).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ptrl_jax.config import ConfigError

AXIS = "envs"
"""The mesh axis the env batch is split over."""


class DevicesError(ConfigError):
    """A ``devices=`` value or env count the program cannot be laid out with."""


def resolve_devices(devices: str, available: int | None = None, processes: int | None = None) -> int:
    """``devices`` (``all`` or a positive count) as a number of local devices; with several
    processes (``jax.distributed``, ``ptrl_jax/io/hosts.py``), all devices of all processes."""
    processes = jax.process_count() if processes is None else processes
    text = str(devices).strip().lower()
    if processes > 1:
        total = jax.device_count() if available is None else available
        if text not in ("all", str(total)):
            raise DevicesError(f"devices={devices}: over {processes} processes the program runs on all "
                               f"{total} devices of all of them; give devices=all")
        return total
    available = jax.local_device_count() if available is None else available
    if text == "all":
        return available
    try:
        n = int(text)
    except ValueError:
        raise DevicesError(f"devices={devices!r}: give all or a number of devices (1 to {available})") from None
    if not 1 <= n <= available:
        raise DevicesError(f"devices={n}: this process sees {available} {jax.default_backend()} device(s); "
                           f"give 1 to {available} or all")
    return n


def check_divisible(env_counts: dict[str, int], n: int) -> None:
    """Refuse a stage whose env count does not split evenly over ``n`` devices, naming it."""
    bad = {stage: count for stage, count in env_counts.items() if count % n}
    if bad:
        detail = ", ".join(f"{stage} has {count} envs" for stage, count in bad.items())
        raise DevicesError(f"devices={n}: every stage's env count must divide by {n}; {detail} "
                           f"(set num_envs to a multiple of {n})")


def make_mesh(n: int) -> Mesh:
    """A one-axis mesh over the first ``n`` local devices, or over every process's devices
    when several processes take part."""
    devices = jax.devices() if jax.process_count() > 1 else jax.local_devices()[:n]
    return Mesh(np.asarray(devices), (AXIS,))


def _env_sharded(mesh: Mesh, tree: Any, axis: int, num_envs: int) -> Any:
    """Each leaf of ``tree`` split over the mesh along ``axis`` where that axis holds the envs;
    any other leaf replicated."""
    def spec(leaf):
        shape = getattr(leaf, "shape", ())
        if len(shape) > axis and shape[axis] == num_envs:
            return NamedSharding(mesh, PartitionSpec(*([None] * axis), AXIS))
        return NamedSharding(mesh, PartitionSpec())

    return jax.tree.map(spec, tree)


def state_shardings(mesh: Mesh, state: Any, source_envs: int, target_envs: dict[str, int]) -> Any:
    """Shardings for a ``program.ProgramState`` (or its shape): the source's env states and
    episode accumulators split on axis 0, each target's on axis 2 (after presets and seeds);
    params, optimiser state, normalisers, metrics, keys and counters replicated."""
    replicated = NamedSharding(mesh, PartitionSpec())
    out = jax.tree.map(lambda _: replicated, state)
    src = out.source._replace(
        env_state=_env_sharded(mesh, state.source.env_state, 0, source_envs),
        episodes=_env_sharded(mesh, state.source.episodes, 0, source_envs))
    targets = {
        robot: out.targets[robot]._replace(
            env_state=_env_sharded(mesh, t.env_state, 2, target_envs[robot]),
            episodes=_env_sharded(mesh, t.episodes, 2, target_envs[robot]))
        for robot, t in state.targets.items()
    }
    return out._replace(source=src, targets=targets)

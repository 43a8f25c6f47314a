"""Several hosts (issue 22): one program over the devices of every process, through
``jax.distributed``.

Each host (or each process on one host) runs the same command with its own ``process_id``::

    python -m ptrl_jax.run exp=go2_to_xbot scale=paper devices=all engine=mjx \\
        coordinator=10.0.0.1:1234 num_processes=2 process_id=0      # on host 0
    python -m ptrl_jax.run exp=go2_to_xbot scale=paper devices=all engine=mjx \\
        coordinator=10.0.0.1:1234 num_processes=2 process_id=1      # on host 1

or ``distributed=auto`` under a cluster scheduler whose environment jax reads (SLURM, Open MPI,
Cloud TPU, ...). The mesh of ``ptrl_jax/core/sharding.py`` then spans every process's devices,
and XLA's collectives (Gloo on CPUs, NCCL on GPUs) carry the gradient and statistic means.

What changes at the edges, and nothing in the jitted core:
- ``jax.distributed.initialize`` must run before jax creates its backend, so these keys are read
  from the command line before anything else (``start_from_argv``) and are not config keys;
- process 0 alone writes the run folder; the others compute and wait;
- host reads of env-sharded leaves (checkpoints, outputs) gather them first (``fetch``);
- the processes meet at barriers of the coordination service (``barrier``) after compiling,
  before a resumed state is placed on the devices, and after every write of process 0, because
  Gloo gives a peer only about 30 s to join a collective, less than one process's compile, load or
  write can lag another's (measured, docs/scaling.md);
- a Ctrl-C or SIGTERM on any process stops all of them at the same slice (``any_process``);
- a process other than 0 checks that the coordinator's port answers within ``host_timeout``
  seconds before it initializes: an unreachable coordinator otherwise ends the process from C++
  after the timeout, with no Python error to name it.

This module imports jax lazily: it runs before the backend exists.
"""

from __future__ import annotations

import socket
import sys
import time
from dataclasses import dataclass
from typing import Any

from ptrl_jax.config import ConfigError

HOST_KEYS = ("coordinator", "num_processes", "process_id", "host_timeout", "distributed")
"""Command-line keys read before jax starts (not config keys; a resume takes them again)."""

DEFAULT_TIMEOUT_S = 300.0
"""How long a process waits for the coordinator, and at each barrier for the others."""


class HostsError(ConfigError):
    """A host setting that cannot start, named with its value."""


@dataclass(frozen=True)
class HostSpec:
    """How this process joins the others."""

    coordinator: str | None
    """``HOST:PORT`` of process 0's coordination service; None with ``distributed=auto``."""
    num_processes: int | None
    """How many processes take part (None: from the cluster's environment)."""
    process_id: int | None
    """This process's index, 0 to ``num_processes - 1`` (None: from the cluster's environment)."""
    timeout_s: float = DEFAULT_TIMEOUT_S
    """Seconds to wait for the coordinator, at each barrier, and for a silent process's heartbeat
    (at least jax's 100 s)."""


def parse_host_args(argv: list[str]) -> tuple[HostSpec | None, list[str]]:
    """(the host spec, or None for a single process; the other arguments). Refuses an incomplete
    or inconsistent set, naming the key."""
    found: dict[str, str] = {}
    rest = []
    for arg in argv:
        key, sep, value = arg.partition("=")
        if sep and key in HOST_KEYS:
            found[key] = value
        else:
            rest.append(arg)
    if not found:
        return None, rest
    try:
        timeout = float(found.get("host_timeout", DEFAULT_TIMEOUT_S))
    except ValueError:
        raise HostsError(f"host_timeout={found['host_timeout']!r}: give seconds, e.g. host_timeout=120") from None
    if timeout <= 0:
        raise HostsError(f"host_timeout={timeout:g}: give a positive number of seconds")
    if "distributed" in found:
        if found["distributed"] != "auto":
            raise HostsError(f"distributed={found['distributed']!r}: the only value is auto (the cluster's "
                             "environment sets the processes); or give coordinator=, num_processes=, process_id=")
        extra = sorted(set(found) & {"coordinator", "num_processes", "process_id"})
        if extra:
            raise HostsError(f"distributed=auto takes the processes from the cluster's environment; drop {extra}")
        return HostSpec(None, None, None, timeout), rest
    missing = [k for k in ("coordinator", "num_processes", "process_id") if k not in found]
    if missing:
        raise HostsError(f"several hosts need coordinator=HOST:PORT, num_processes=N and process_id=K; "
                         f"missing {missing}")
    host, sep, port = found["coordinator"].rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise HostsError(f"coordinator={found['coordinator']!r}: give HOST:PORT, e.g. coordinator=10.0.0.1:1234")
    try:
        n, k = int(found["num_processes"]), int(found["process_id"])
    except ValueError:
        raise HostsError(f"num_processes={found['num_processes']!r} and process_id={found['process_id']!r} "
                         "must be whole numbers") from None
    if n < 1:
        raise HostsError(f"num_processes={n}: give 1 or more")
    if not 0 <= k < n:
        raise HostsError(f"process_id={k}: with num_processes={n} it must be 0 to {n - 1}")
    return HostSpec(found["coordinator"], n, k, timeout), rest


def wait_for_coordinator(address: str, timeout_s: float) -> None:
    """Return once ``address`` accepts a TCP connection; refuse after ``timeout_s``, naming it."""
    host, _, port = address.rpartition(":")
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            with socket.create_connection((host, int(port)), timeout=min(5.0, timeout_s)):
                return
        except OSError as e:
            if time.monotonic() >= deadline:
                raise HostsError(f"coordinator={address}: nothing answered there within host_timeout={timeout_s:g} s "
                                 f"({e.__class__.__name__}: {e}); start process 0 first, or check the address") from None
            time.sleep(0.2)


def start(spec: HostSpec) -> None:
    """Join the other processes (``jax.distributed.initialize``). Before jax's backend exists."""
    import jax

    if spec.process_id not in (None, 0):
        wait_for_coordinator(spec.coordinator, spec.timeout_s)
    # If a process never joins, jax ends every waiting process from C++ after the timeout
    # ("DEADLINE_EXCEEDED ... RegisterTask", exit 1) with no Python error; this line says what
    # it was waiting for.
    who = "this process" if spec.process_id is None else f"process {spec.process_id} of {spec.num_processes}"
    print(f"{who}: joining the others at coordinator={spec.coordinator or '(from the cluster environment)'}, "
          f"waiting up to {spec.timeout_s:g} s (host_timeout)", file=sys.stderr, flush=True)
    try:
        # Heartbeats too wait host_timeout, not jax's 100 s: on 2 loaded cores a CI run once saw
        # process 0 declared dead mid-compile ("stopped sending heartbeats") and both exit.
        jax.distributed.initialize(spec.coordinator, spec.num_processes, spec.process_id,
                                   initialization_timeout=max(1, int(spec.timeout_s)),
                                   heartbeat_timeout_seconds=max(100, int(spec.timeout_s)))
    except RuntimeError as e:  # the backend exists already, or the cluster was not detected
        raise HostsError(f"jax.distributed could not start: {e}. Host keys work on the command line "
                         "(python -m ptrl_jax.run ... coordinator=...), before anything runs jax") from None


def start_from_argv(argv: list[str]) -> list[str]:
    """Read the host keys from ``argv`` and join the other processes if there are any; return the
    remaining arguments. A no-op (the arguments unchanged) without host keys."""
    spec, rest = parse_host_args(argv)
    if spec is not None and not already_started():
        start(spec)
    return rest


def already_started() -> bool:
    import jax

    return jax.distributed.is_initialized()


def process_count() -> int:
    import jax

    return jax.process_count()


def process_index() -> int:
    import jax

    return jax.process_index()


def is_main() -> bool:
    """Whether this process writes the run folder (process 0, or the only process)."""
    import jax

    return jax.process_index() == 0


def fetch(tree: Any) -> Any:
    """``tree`` readable on this host: unchanged in one process; with several, every leaf
    gathered in full to every process (a collective: all processes call it together)."""
    if process_count() == 1:
        return tree
    from jax.experimental import multihost_utils

    return multihost_utils.process_allgather(tree, tiled=True)


def any_process(flag: bool) -> bool:
    """Whether ``flag`` is set on any process (a collective; ``flag`` itself in one process)."""
    if process_count() == 1:
        return flag
    import numpy as np
    from jax.experimental import multihost_utils

    return bool(np.any(multihost_utils.process_allgather(np.int32(flag))))


def barrier(name: str, timeout_s: float = DEFAULT_TIMEOUT_S) -> None:
    """Wait until every process reaches the barrier ``name`` (a no-op in one process). Through
    the coordination service, not a device collective, so that it can wait longer than Gloo's
    30 s."""
    global _barriers
    if process_count() == 1:
        return
    from jax._src import distributed  # the coordination client; jax has no public barrier without devices

    _barriers += 1  # every process passes the same barriers in the same order: unique ids
    distributed.global_state.client.wait_at_barrier(f"ptrl_jax-{_barriers}-{name}", int(timeout_s * 1000))


_barriers = 0

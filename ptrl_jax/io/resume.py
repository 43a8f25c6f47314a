"""Stopping and resuming a run: the whole program state saved between slices
(``resume_state.npz``), the runtime it must be resumed under, and the Ctrl-C / SIGTERM handler
that stops a run at the end of a slice instead of killing it."""

from __future__ import annotations

import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import jax

from envs.mujoco_engine import resolve_engine
from ptrl_jax.config import ConfigError, ExperimentConfig
from ptrl_jax.core import sharding
from ptrl_jax.core.program import Program
from ptrl_jax.io import artifacts
from ptrl_jax.io.progress import Progress


RESUME_STATE = "resume_state.npz"
"""The whole program state, written every ``checkpoint_every`` iterations and on Ctrl-C/SIGTERM."""


class StopRequest:
    """Ctrl-C / SIGTERM set a flag instead of killing the process: the run saves its state at
    the end of the current slice and exits cleanly. A second Ctrl-C aborts at once (the last
    saved state is still there)."""

    def __init__(self):
        self.requested = False
        self._previous: dict[int, Any] = {}

    def _handler(self, signum, frame) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True
        print(f"\n{signal.Signals(signum).name}: saving the run state at the next checkpoint "
              f"(Ctrl-C again to abort now)", file=sys.stderr)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        return False


def runtime_fingerprint(cfg: ExperimentConfig) -> dict[str, str]:
    """What a run's float results depend on besides its config and state: library versions,
    XLA flags, the device and the physics engine. A resume must match it bitwise."""
    import jaxlib
    import mujoco

    return {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__,
            "xla_flags": os.environ.get("XLA_FLAGS", ""), "device": jax.devices()[0].device_kind,
            "engine": resolve_engine(cfg.engine), "devices": str(sharding.resolve_devices(cfg.devices)),
            "processes": str(jax.process_count())}


def check_runtime(saved: dict[str, str], cfg: ExperimentConfig, run_dir: Path) -> None:
    """Refuse to resume under another runtime, naming each difference."""
    now = runtime_fingerprint(cfg)
    diff = [f"{k}: saved {saved[k]!r}, now {now[k]!r}" for k in now if k in saved and saved[k] != now[k]]
    if diff:
        raise ConfigError(f"resume={run_dir}: the run was saved under another runtime, so it would not "
                          f"continue bitwise ({'; '.join(diff)}); resume it where it ran, or start it anew")


def save_resume_state(cfg: ExperimentConfig, run_dir: Path, state: Any, progress: "Progress") -> None:
    times = [[s, r, i, t] for (s, r, i), t in progress.times.items()]
    meta = {"experiment": cfg.name, "jax": jax.__version__, "runtime": runtime_fingerprint(cfg), "times": times,
            "stage_start": progress.stage_start,
            "source_iteration": Program.iterations(state)[0],
            "target_iteration": Program.iterations(state)[1]}
    artifacts.save_state(run_dir / RESUME_STATE, state, meta)

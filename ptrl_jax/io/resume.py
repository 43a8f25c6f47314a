"""Stopping and resuming a run: the whole program state saved between slices
(``resume_state.npz``), the runtime it must be resumed under, and the Ctrl-C / SIGTERM handler
that stops a run at the end of a slice instead of killing it."""

from __future__ import annotations

import functools
import os
import signal
import sys
import threading
from pathlib import Path
from typing import Any

import jax

import envs
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


VECTOR_ISA_FLAGS = ("sse4_2", "avx", "fma", "avx2", "avx512f", "avx512dq", "avx512bw", "avx512vl",
                    "avx512_vnni", "avx512_bf16", "avx512_fp16", "amx_tile", "amx_bf16", "amx_fp16")
"""The x86 vector-ISA flags (as /proc/cpuinfo spells them) that XLA's CPU backend may compile
for. XLA targets the host's, so two machines with different sets run other instructions for the
same program, whose float results differ in the last bits; training amplifies that into another
run (capping XLA at AVX on an AVX2 host changed every actor layer within 3 iterations,
docs/table4.md, stop 52)."""


def parse_cpuinfo(text: str) -> tuple[str, str]:
    """(model, vector ISA) of the first processor in a /proc/cpuinfo text. The model is its model
    name with its family and model numbers (VMs often show a bare 'AMD EPYC'); the ISA is the
    flags of ``VECTOR_ISA_FLAGS`` it has, space-separated in that order ('' where it lists none)."""
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if fields:
                break  # the first processor's block is enough: a VM's cores share one model
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    flags = set(fields.get("flags", "").split())
    model = fields.get("model name", "")
    if "cpu family" in fields and "model" in fields:
        model = f"{model} (family {fields['cpu family']} model {fields['model']})".strip()
    return model, " ".join(f for f in VECTOR_ISA_FLAGS if f in flags)


@functools.cache  # the CPU does not change under a process; the fingerprint is taken every slice
def host_cpu() -> tuple[str, str]:
    """(model name, vector ISA) of this machine's CPU from /proc/cpuinfo; where there is none
    (not Linux), the platform's processor string and ''."""
    try:
        return parse_cpuinfo(Path("/proc/cpuinfo").read_text())
    except OSError:
        import platform

        return platform.processor() or platform.machine(), ""


def runtime_fingerprint(cfg: ExperimentConfig) -> dict[str, str]:
    """What a run's float results depend on besides its config and state: library versions,
    XLA flags, the device, the physics engine, the robots' MJCF files (``models``: each trained
    stage's asset and its ``envs.asset_sha256``) and, on CPU, the instruction set XLA compiles for
    (``cpu_isa``). A resume must match it bitwise. A state saved before a key existed is not
    checked on that key."""
    import jaxlib
    import mujoco

    fingerprint = {"jax": jax.__version__, "jaxlib": jaxlib.__version__, "mujoco": mujoco.__version__,
                   "xla_flags": os.environ.get("XLA_FLAGS", ""), "device": jax.devices()[0].device_kind,
                   "engine": resolve_engine(cfg.engine), "devices": str(sharding.resolve_devices(cfg.devices)),
                   "processes": str(jax.process_count()), "models": models_fingerprint(cfg)}
    if jax.devices()[0].platform == "cpu":  # on an accelerator XLA's float results do not follow the host
        fingerprint["cpu_isa"] = host_cpu()[1]
    return fingerprint


def models_fingerprint(cfg: ExperimentConfig) -> str:
    """``asset=sha256`` of every robot model the run trains on (the source's only when it trains
    one), sorted: ``"go2.xml=1a2b...; xbot_l.xml=3c4d..."``."""
    stages = ([cfg.source] if cfg.trains_source else []) + list(cfg.targets.values())
    return "; ".join(sorted({f"{st.env.asset}={envs.asset_sha256(st.env.asset)}" for st in stages}))


def _models_diff(saved: str, now: str) -> list[str]:
    """Each robot model that changed between two ``models_fingerprint``s, by file name."""
    parse = lambda text: dict(part.split("=", 1) for part in text.split("; ") if "=" in part)  # noqa: E731
    old, new = parse(saved), parse(now)
    return [f"model {asset}: saved sha256 {old.get(asset, 'none')}, now {new.get(asset, 'none')}"
            for asset in sorted(set(old) | set(new)) if old.get(asset) != new.get(asset)]


def check_runtime(saved: dict[str, str], cfg: ExperimentConfig, run_dir: Path) -> None:
    """Refuse to resume under another runtime, naming each difference."""
    now = runtime_fingerprint(cfg)
    diff = [f"{k}: saved {saved[k]!r}, now {now[k]!r}" for k in now
            if k != "models" and k in saved and saved[k] != now[k]]
    if "models" in saved:
        diff += _models_diff(saved["models"], now["models"])
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

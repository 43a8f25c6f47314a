"""Scaling benchmark (not a test): the PTRL program on 1 and on N local devices, side by side in
one process. ``python experiments/bench_devices.py [exp=go2_from_scratch] [envs=1024]
[iterations=3] [engines=mjx,mujoco] [devices=1,2] [key=value ...]``

On a CPU, jax sees one device unless told otherwise; this script asks XLA for as many host
devices as the largest count in ``devices=`` (``--xla_force_host_platform_device_count``), so on
a 2-core machine ``devices=1,2`` splits the same two cores into two devices. On a GPU node it
uses the GPUs there.

Prints per engine and device count: the program's compile time and the training rate in env
steps/s (target iterations of ``exp``, timed after one warm-up iteration), and each count's
rate as a ratio of one device's. Extra ``key=value`` arguments are config overrides.

``processes=N`` (N > 1) adds the same program over N processes on this machine, one device each,
joined through ``jax.distributed`` on 127.0.0.1 (``ptrl_jax/io/hosts.py``): the script starts N
copies of itself with the host keys, and process 0 prints the row. MJX only (MuJoCo C's physics
cannot serve another process's envs).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def several_processes(argv: list[str], n: int) -> None:
    """Start ``n`` copies of this script joined through jax.distributed; return when all end."""
    import socket
    import subprocess

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    rest = [a for a in argv if not a.startswith(("processes=", "devices="))]
    procs = [subprocess.Popen([sys.executable, __file__, *rest, "devices=all", f"coordinator=127.0.0.1:{port}",
                               f"num_processes={n}", f"process_id={k}"],
                              stdout=None if k == 0 else subprocess.DEVNULL) for k in range(n)]
    codes = [p.wait() for p in procs]
    if any(codes):
        raise SystemExit(f"the {n} processes exited with {codes}")


def main(argv: list[str]) -> None:
    from ptrl_jax.io.hosts import start_from_argv  # before jax's backend exists

    argv = start_from_argv(argv)
    opts = dict(a.split("=", 1) for a in argv)
    processes = int(opts.pop("processes", "1"))
    joined = opts.get("devices") == "all"  # a copy started by several_processes
    counts = [int(c) for c in opts.pop("devices", "1,2").split(",")] if not joined else [0]
    if joined:
        opts.pop("devices")
    if not joined and "--xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                                   + f" --xla_force_host_platform_device_count={max(counts)}").strip()
    import jax
    import numpy as np

    from experiments.bench import machine
    from ptrl_jax import run as run_cli
    from ptrl_jax.io import hosts
    from ptrl_jax.io.checkpoints import load_init_target, load_source_params
    from ptrl_jax.io.progress import Progress
    from ptrl_jax.io.overrides import load_experiment

    exp = opts.pop("exp", "go2_from_scratch")
    envs_n = int(opts.pop("envs", "1024"))
    iters = int(opts.pop("iterations", "3"))
    engines = opts.pop("engines", "mjx,mujoco").split(",")
    if not joined:
        print(machine())
        print(f"{exp}: {envs_n} envs per stage, {iters} timed iterations after one warm-up")
        print(f"{'engine':8s} {'devices':>7s} {'compile s':>10s} {'env steps/s':>12s} {'vs 1 device':>12s}")
    for engine in engines:
        base = None
        for n in counts:
            if joined:
                n = jax.device_count()
            overrides = [f"engine={engine}", f"devices={'all' if joined else n}", f"target.ppo.num_envs={envs_n}",
                         f"target.ppo.num_iterations={iters + 1}", "target.ppo.final_noise_iterations=0", "progress=false", "checkpoint_every=1",
                         *[f"{k}={v}" for k, v in opts.items()]]
            cfg = load_experiment(exp, overrides)
            progress = Progress(cfg, False)
            key = jax.random.PRNGKey(cfg.seed)
            t = time.monotonic()
            program, init, advance, _ = run_cli._compiled_program(cfg, progress, key, np.int32(1), n)
            state = init(key, load_source_params(cfg, program), load_init_target(cfg, program))
            hosts.barrier("compiled")  # several processes: one compile can lag the other's past Gloo's 30 s
            state = jax.block_until_ready(advance(state, np.int32(1)))  # warm-up iteration
            compile_s = time.monotonic() - t
            t = time.monotonic()
            for _ in range(iters):
                state = jax.block_until_ready(advance(state, np.int32(1)))
            seconds = time.monotonic() - t
            steps = iters * cfg.target.ppo.num_envs * cfg.target.ppo.unroll_length * len(cfg.variants) * cfg.seeds
            rate = steps / seconds
            base = base or rate
            if joined:
                if jax.process_index() == 0:
                    print(f"{engine:8s} {n:7d} {compile_s:10.1f} {rate:12,.0f}   ({jax.process_count()} processes, "
                          "one device each)", flush=True)
                continue
            print(f"{engine:8s} {n:7d} {compile_s:10.1f} {rate:12,.0f} {rate / base:12.2f}", flush=True)
    if processes > 1 and not joined:
        several_processes(argv, processes)


if __name__ == "__main__":
    main(sys.argv[1:])

"""Run by tests/test_devices.py in a subprocess that sees two CPU devices (XLA_FLAGS
--xla_force_host_platform_device_count=2): A1 from scratch at smoke size, 2 seeds, MuJoCo C,
on one device, on two, and on two interrupted after its first saved slice and resumed.
Prints one JSON line: each run's folder."""

import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import jax

from ptrl_jax import run as run_cli
from ptrl_jax.io.overrides import load_experiment
from ptrl_jax.io.resume import RESUME_STATE


def config(out: Path, devices: str):
    return load_experiment("a1_from_scratch", [
        "scale=smoke", f"runs_dir={out}", f"devices={devices}", "seeds=2", "engine=mujoco", "checkpoint_every=1",
        "target.ppo.num_iterations=3", "progress=false", "report.zero_shot_check=false"])


def interrupt_when_saved(folder: Path) -> None:
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline:
        if list(folder.glob(f"*/*/{RESUME_STATE}")):
            os.kill(os.getpid(), signal.SIGINT)
            return
        time.sleep(0.002)


def main(out: str) -> None:
    out = Path(out)
    assert jax.device_count() == 2, jax.devices()
    runs = {}
    for name, devices in (("one", "1"), ("two", "2")):
        runs[name] = str(run_cli.run(config(out / name, devices))["run_dir"])
    watcher = threading.Thread(target=interrupt_when_saved, args=(out / "cut",), daemon=True)
    watcher.start()
    cut = run_cli.run(config(out / "cut", "2"))
    watcher.join()
    resumed = run_cli.resume(cut["run_dir"], show_progress=False)
    runs.update(interrupted=bool(cut["interrupted"]), resumed=str(resumed["run_dir"]))
    print(json.dumps(runs))


if __name__ == "__main__":
    main(sys.argv[1])

"""Several processes (issue 22, ``ptrl_jax/io/hosts.py``): the host keys refused before anything
starts, an unreachable coordinator named within a bounded time; and (slow) two processes on
127.0.0.1 with one CPU device each, started with the command a user types, against the
one-process run, then a pair stopped by a signal on one of them and resumed by both."""

import csv
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from ptrl_jax import run as run_cli
from ptrl_jax.core import sharding
from ptrl_jax.io import hosts
from ptrl_jax.io.hosts import HostsError, parse_host_args
from ptrl_jax.io.overrides import ConfigError, load_experiment

ROOT = Path(__file__).resolve().parents[1]
HOST = ["coordinator=127.0.0.1:1234", "num_processes=2", "process_id=1"]


class TestHostArgs:
    def test_host_keys_are_taken_out_and_the_rest_kept(self):
        spec, rest = parse_host_args(["exp=a1_from_scratch", *HOST, "host_timeout=20", "seeds=2"])
        assert rest == ["exp=a1_from_scratch", "seeds=2"]
        assert (spec.coordinator, spec.num_processes, spec.process_id, spec.timeout_s) == ("127.0.0.1:1234", 2, 1, 20.0)
        assert parse_host_args(["exp=a1_from_scratch"]) == (None, ["exp=a1_from_scratch"])
        auto, _ = parse_host_args(["distributed=auto"])
        assert (auto.coordinator, auto.num_processes, auto.process_id) == (None, None, None)

    @pytest.mark.parametrize("args, message", [
        (["coordinator=127.0.0.1:1234", "num_processes=2"], r"missing \['process_id'\]"),
        (["coordinator=127.0.0.1", "num_processes=2", "process_id=0"], "coordinator='127.0.0.1': give HOST:PORT"),
        (["coordinator=127.0.0.1:99999", "num_processes=2", "process_id=0"], "give HOST:PORT"),
        (["coordinator=127.0.0.1:1234", "num_processes=2", "process_id=2"], "process_id=2: with num_processes=2 it must be 0 to 1"),
        (["coordinator=127.0.0.1:1234", "num_processes=two", "process_id=0"], "must be whole numbers"),
        ([*HOST, "host_timeout=0"], "host_timeout=0: give a positive"),
        ([*HOST, "host_timeout=soon"], "host_timeout='soon': give seconds"),
        (["distributed=yes"], "distributed='yes': the only value is auto"),
        (["distributed=auto", "process_id=0"], r"drop \['process_id'\]"),
    ])
    def test_bad_host_keys_are_named(self, args, message):
        with pytest.raises(HostsError, match=message):
            parse_host_args(args)

    def test_one_process_needs_no_host_keys(self):
        assert hosts.process_count() == 1 and hosts.is_main() and not hosts.already_started()
        tree = {"a": np.arange(3)}
        assert hosts.fetch(tree) is tree and hosts.any_process(True) and not hosts.any_process(False)
        hosts.barrier("alone")  # returns at once


class TestRefusals:
    def test_devices_over_several_processes_are_all_of_them(self):
        assert sharding.resolve_devices("all", available=4, processes=2) == 4
        assert sharding.resolve_devices("4", available=4, processes=2) == 4
        with pytest.raises(ConfigError, match="devices=1: over 2 processes the program runs on all 4 devices"):
            sharding.resolve_devices("1", available=4, processes=2)

    def test_mujoco_c_engine_is_refused_over_several_processes(self, monkeypatch):
        cfg = load_experiment("a1_from_scratch", ["scale=smoke", "engine=mujoco"])
        run_cli.check_engine_for_hosts(cfg)  # one process: fine
        monkeypatch.setattr(hosts, "process_count", lambda: 2)
        with pytest.raises(ConfigError, match="engine=mujoco runs the physics in one process's MuJoCo C thread "
                                              "pool; over 2 processes use engine=mjx"):
            run_cli.check_engine_for_hosts(cfg)
        run_cli.check_engine_for_hosts(load_experiment("a1_from_scratch", ["scale=smoke", "engine=mjx"]))

    def test_unreachable_coordinator_is_named_within_its_timeout(self, tmp_path):
        """Process 1 with nothing listening at the coordinator's address: exit 2, the address
        named, in about host_timeout seconds (jax alone would end the process from C++ after
        its own timeout, with no Python error), and no run folder."""
        port = free_port()
        t = time.monotonic()
        proc = subprocess.run([sys.executable, "-m", "ptrl_jax.run", "exp=a1_from_scratch", "scale=smoke",
                               f"runs_dir={tmp_path}", f"coordinator=127.0.0.1:{port}", "num_processes=2",
                               "process_id=1", "host_timeout=2"],
                              cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 2, proc.stderr[-2000:]
        assert f"coordinator=127.0.0.1:{port}: nothing answered there within host_timeout=2 s" in proc.stderr
        assert time.monotonic() - t < 60 and not list(tmp_path.iterdir())


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def read_metrics(folder: Path) -> list[dict]:
    (path,) = folder.glob("*/*/metrics.csv")
    return list(csv.DictReader(open(path)))


SMOKE = ["exp=a1_from_scratch", "scale=smoke", "seeds=2", "engine=mjx", "checkpoint_every=1",
         "target.ppo.num_iterations=3", "progress=false", "report.zero_shot_check=false"]


def _start_runs(out: Path):
    """(start, pair, finish) for ptrl_jax.run processes writing their logs under ``out``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT),
           "JAX_COMPILATION_CACHE_DIR": str(jax.config.jax_compilation_cache_dir),
           "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "2"}

    def start(args, log):
        return subprocess.Popen([sys.executable, "-m", "ptrl_jax.run", *args], cwd=ROOT, env=env,
                                stdout=open(log, "w"), stderr=subprocess.STDOUT, text=True)

    def pair(args, name):
        port = free_port()
        return [start([*args, f"coordinator=127.0.0.1:{port}", "num_processes=2", f"process_id={k}"],
                      out / f"{name}{k}.log") for k in (0, 1)]

    def finish(procs, timeout=600):
        return [p.wait(timeout=timeout) for p in procs]

    return start, pair, finish


def _logs(out: Path) -> dict:
    return {p.name: p.read_text()[-3000:] for p in out.glob("*.log")}


# Slow: three processes that each compile their own program (the pair's two processes and the
# reference do not share XLA's persistent cache: each process's program has its own key,
# measured 2026-12-07), 244 s of setup in a 19-minute suite on a 2-core Zen 3, over its 15-minute
# budget. The default suite keeps the sharded program on two devices in one process
# (tests/test_devices.py), the host keys and the unreachable coordinator above;
# `python -m pytest -q -m slow` runs this pair and the signal test below.
@pytest.mark.slow
@pytest.mark.xdist_group("two_processes")
class TestTwoProcesses:
    """A1 from scratch at smoke size, 2 seeds, MJX (MuJoCo C's thread pool cannot serve another
    host), on one process and on two that meet through jax.distributed on 127.0.0.1."""

    @pytest.fixture(scope="class")
    def runs(self, tmp_path_factory):
        out = tmp_path_factory.mktemp("hosts")
        start, pair, finish = _start_runs(out)
        # the one-process reference and the pair side by side
        one = start([*SMOKE, f"runs_dir={out / 'one'}"], out / "one.log")
        two = pair([*SMOKE, "devices=all", f"runs_dir={out / 'two'}"], "two")
        codes = {"one": finish([one])[0], "two": finish(two)}
        return {"out": out, "codes": codes, "logs": _logs(out)}

    def test_two_processes_match_one_within_float_order(self, runs):
        """Every metric of all 3 iterations (measured: within 4.4e-6 relative, the total loss)."""
        assert runs["codes"]["one"] == 0 and runs["codes"]["two"] == [0, 0], runs["logs"]
        one, two = read_metrics(runs["out"] / "one"), read_metrics(runs["out"] / "two")
        assert [(r["seed"], r["iteration"]) for r in one] == [(r["seed"], r["iteration"]) for r in two]
        assert len(one) == 6  # 2 seeds x 3 iterations
        for a, b in zip(one, two):
            for key in a:
                if key not in ("stage", "robot", "preset", "wall_time_s"):
                    np.testing.assert_allclose(float(b[key]), float(a[key]), rtol=1e-4, atol=1e-6, err_msg=key)

    def test_only_process_0_writes_and_the_report_names_the_processes(self, runs):
        (folder,) = (runs["out"] / "two").glob("*/*")
        assert "2 of 2 device(s)) over 2 processes" in (folder / "report.md").read_text()
        assert len(list((runs["out"] / "two").glob("*/*"))) == 1
        assert "process 1 of 2: done; process 0 writes the run folder" in runs["logs"]["two1.log"]


@pytest.mark.slow
@pytest.mark.xdist_group("two_processes")
class TestTwoProcessesSignal:
    """A pair stopped by SIGINT to process 1 alone once process 0 has saved its first slice, then
    both resumed, against an uninterrupted pair. Slow (six processes, 178 s of setup alone on 2
    cores, 2026-12-06); TestTwoProcesses keeps the pair against one process."""

    @pytest.fixture(scope="class")
    def runs(self, tmp_path_factory):
        out = tmp_path_factory.mktemp("hosts_signal")
        _, pair, finish = _start_runs(out)
        codes = {"two": finish(pair([*SMOKE, "devices=all", f"runs_dir={out / 'two'}"], "two"))}
        cut = pair([*SMOKE, "devices=all", f"runs_dir={out / 'cut'}"], "cut")
        deadline = time.monotonic() + 600
        while not list((out / "cut").glob("*/*/resume_state.npz")) and time.monotonic() < deadline:
            time.sleep(0.002)
        cut[1].send_signal(signal.SIGINT)
        codes["cut"] = finish(cut)
        (cut_dir,) = (out / "cut").glob("*/*")
        interrupted = not (cut_dir / "report.md").exists()
        if interrupted:
            codes["resumed"] = finish(pair([f"resume={cut_dir}"], "resumed"))
        return {"out": out, "codes": codes, "interrupted": interrupted, "cut": cut_dir, "logs": _logs(out)}

    def test_a_signal_to_one_process_stops_both_and_both_resume_bitwise(self, runs):
        assert runs["interrupted"], "the run finished before the signal took effect"
        assert runs["codes"]["cut"] == [130, 130], runs["logs"]
        assert runs["codes"]["resumed"] == [0, 0], runs["logs"]
        strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rows]  # noqa: E731
        assert strip(read_metrics(runs["out"] / "cut")) == strip(read_metrics(runs["out"] / "two"))
        (two,) = (runs["out"] / "two").glob("*/*")
        names = sorted(p.name for p in two.glob("*.npz"))
        assert names == ["target_scratch_seed0.npz", "target_scratch_seed1.npz"]
        for name in names:
            ref, got = np.load(two / name), np.load(runs["cut"] / name)
            for key in ref.files:
                if key != "meta":
                    assert np.array_equal(ref[key], got[key]), (name, key)

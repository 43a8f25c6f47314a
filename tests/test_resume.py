"""Resume and faults: a killed run continues to the same result; bad checkpoints are named."""

import csv
import dataclasses
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from ptrl_jax import run as run_cli
from ptrl_jax.io import artifacts
from ptrl_jax.io.artifacts import CheckpointError
from ptrl_jax.evaluate import policy_from_checkpoint
from ptrl_jax.io.overrides import ConfigError
from ptrl_jax.io.resume import RESUME_STATE, check_runtime, host_cpu, parse_cpuinfo, runtime_fingerprint

# One xdist worker runs every test of the shared smoke run (tests/conftest.py: smoke_run).
pytestmark = pytest.mark.xdist_group("smoke_go2_to_xbot")

ROOT = Path(__file__).resolve().parents[1]


def start_smoke_run(runs_dir: Path, *extra: str, exp: str = "go2_to_xbot") -> subprocess.Popen:
    return start_cli(["exp=" + exp, "scale=smoke", f"runs_dir={runs_dir}", *extra])


def start_cli(args: list[str]) -> subprocess.Popen:
    """``python -m ptrl_jax.run ARGS`` as a user types it, in a new process."""
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        # The test session's compilation cache (the init and env programs hit it).
        "JAX_COMPILATION_CACHE_DIR": str(jax.config.jax_compilation_cache_dir),
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "2",
        "JAX_INCLUDE_FULL_TRACEBACKS_IN_LOCATIONS": "0",  # as conftest (see there)
    }
    cmd = [sys.executable, "-m", "ptrl_jax.run", *args]
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def wait_for_saved_state(runs_dir: Path, proc: subprocess.Popen, timeout_s: float = 600, exp: str = "go2_to_xbot") -> Path:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        found = list(runs_dir.glob(f"{exp}/*/{RESUME_STATE}"))
        if found:
            return found[0].parent
        if proc.poll() is not None:
            pytest.fail(f"run ended before saving a state:\n{proc.stdout.read()}")
        time.sleep(0.01)
    proc.kill()
    pytest.fail("no resume state appeared")


def metrics_without_wall_time(run_dir: Path) -> list[dict]:
    rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
    for r in rows:
        r.pop("wall_time_s")
    return rows


class TestKillAndResume:
    def test_kill_9_mid_run_then_resume_matches_uninterrupted(self, smoke_run, tmp_path):
        _, reference = smoke_run
        proc = start_smoke_run(tmp_path)
        run_dir = wait_for_saved_state(tmp_path, proc)
        proc.kill()  # SIGKILL: no handler runs
        proc.wait()
        assert not (run_dir / "report.md").exists(), "the run finished before it was killed"
        saved_at = artifacts.read_state_meta(run_dir / RESUME_STATE)["source_iteration"]

        result = run_cli.resume(run_dir, show_progress=False)
        assert not result["interrupted"]
        assert saved_at >= 1
        assert metrics_without_wall_time(run_dir) == metrics_without_wall_time(reference)
        for ckpt in sorted(reference.glob("*.npz")):
            ref, got = np.load(ckpt), np.load(run_dir / ckpt.name)
            for key in ref.files:
                if key != "meta":
                    assert np.array_equal(ref[key], got[key]), (ckpt.name, key)  # bitwise
        assert not (run_dir / RESUME_STATE).exists()  # finished: state removed


def kill_resume_and_compare(tmp_path: Path, args: list[str], exp: str, timeout_s: float = 900) -> list[str]:
    """Run ``args`` uninterrupted; run it again, kill -9 it after its first saved state, resume
    it with ``resume=DIR`` in a new process; assert metrics and checkpoints bitwise equal.
    Returns the checkpoint names compared."""
    reference = start_cli([*args, f"runs_dir={tmp_path / 'ref'}"])
    out, _ = reference.communicate(timeout=timeout_s)
    assert reference.returncode == 0, out
    (ref_dir,) = (tmp_path / "ref" / exp).iterdir()
    proc = start_cli([*args, f"runs_dir={tmp_path / 'cut'}"])
    run_dir = wait_for_saved_state(tmp_path / "cut", proc, timeout_s=timeout_s, exp=exp)
    proc.kill()  # SIGKILL: no handler runs
    proc.wait()
    assert not (run_dir / "report.md").exists(), "the run finished before it was killed"
    resumed = start_cli([f"resume={run_dir}"])
    out, _ = resumed.communicate(timeout=timeout_s)
    assert resumed.returncode == 0, out
    assert metrics_without_wall_time(run_dir) == metrics_without_wall_time(ref_dir)
    names = sorted(p.name for p in ref_dir.glob("*.npz"))
    assert names and names == sorted(p.name for p in run_dir.glob("*.npz"))
    for name in names:
        ref, got = np.load(ref_dir / name), np.load(run_dir / name)
        for key in ref.files:
            if key != "meta":
                assert np.array_equal(ref[key], got[key]), (name, key)  # bitwise
    return names


# Slow (about 2 min of one core): the suite keeps MuJoCo C's resume through
# tests/test_devices.py's sharded run (SIGINT, then resume in the same process, bitwise) and
# tests/test_learning.py's saved state continued bitwise, and kill -9 through the MJX test above
# (whose resume runs in the test's process: a second CLI process would trace the program again,
# about 2 min); this one is both at once, with the resume a new process as a user types it.
@pytest.mark.slow
@pytest.mark.xdist_group("engine_mujoco_resume")
class TestKillAndResumeWithMujocoC:
    def test_kill_9_then_resume_from_the_command_line_is_bitwise(self, tmp_path):
        """engine=mujoco: the physics state (warm start included) travels in the program state,
        so a run killed after its first checkpoint and resumed by ``python -m ptrl_jax.run
        resume=DIR``, a new process, ends bitwise where an uninterrupted run does. (A1 from
        scratch, 2 seeds: the source-transfer-target chain across a kill is the MJX test's.)"""
        names = kill_resume_and_compare(tmp_path, [
            "exp=a1_from_scratch", "scale=smoke", "engine=mujoco", "seeds=2", "checkpoint_every=1",
            "target.ppo.num_iterations=3", "report.zero_shot_check=false"], "a1_from_scratch")
        assert names == ["target_scratch_seed0.npz", "target_scratch_seed1.npz"]


@pytest.mark.slow
@pytest.mark.xdist_group("cpu_shaped_resume")
class TestKillAndResumeCpuShaped:
    def test_kill_9_then_resume_at_cpu_shapes_is_bitwise(self, tmp_path):
        """A1 from scratch at its scale=cpu shapes (1024 envs x 24 steps, MuJoCo C), 3
        iterations: killed after its first checkpoint and resumed by a new process, it ends
        bitwise where an uninterrupted run does. (Slow: 7 minutes on 2 shared cores.)"""
        names = kill_resume_and_compare(tmp_path, [
            "exp=a1_from_scratch", "scale=cpu", "engine=mujoco", "checkpoint_every=1", "progress=false",
            "target.ppo.num_iterations=3", "target.ppo.final_noise_iterations=1", "report.zero_shot_check=false"],
            "a1_from_scratch", timeout_s=1200)
        assert names == ["target_scratch_seed0.npz"]


class TestResumeUnderAnotherRuntime:
    def test_is_refused_naming_the_difference(self, tmp_path):
        (tmp_path / "config.yaml").write_text("name: go2_to_xbot\nscale: smoke\n")
        runtime = {**runtime_fingerprint(run_cli.build_config({"scale": "smoke"})), "xla_flags": "--xla_other=1",
                   "jax": "0.0.1"}
        artifacts.save_state(tmp_path / RESUME_STATE, {"x": np.zeros(1)}, {"runtime": runtime})
        with pytest.raises(ConfigError, match=r"another runtime.*jax: saved '0.0.1'.*xla_flags: saved '--xla_other=1'"):
            run_cli.resume(tmp_path)
        assert run_cli.main([f"resume={tmp_path}"]) == 2

    def test_a_cpu_with_another_vector_isa_is_refused(self, tmp_path):
        """XLA compiles for the host's vector ISA, so a state saved on an AVX-512 host does not
        continue bitwise on this one (or the reverse): refused, naming both sets."""
        (tmp_path / "config.yaml").write_text("name: go2_to_xbot\nscale: smoke\n")
        runtime = runtime_fingerprint(run_cli.build_config({"scale": "smoke"}))
        assert runtime["cpu_isa"] == host_cpu()[1]  # the suite runs on CPU
        other = "sse4_2 avx" if runtime["cpu_isa"] != "sse4_2 avx" else "sse4_2 avx fma avx2 avx512f"
        artifacts.save_state(tmp_path / RESUME_STATE, {"x": np.zeros(1)},
                             {"runtime": {**runtime, "cpu_isa": other}})
        with pytest.raises(ConfigError, match=rf"another runtime.*cpu_isa: saved '{other}', now '{runtime['cpu_isa']}'"):
            run_cli.resume(tmp_path)

    def test_a_changed_robot_model_is_refused_naming_the_file(self, tmp_path):
        """A state saved on another version of a robot's MJCF (XBot-L's box soles before stop 57)
        has every shape of the new one, so only the fingerprint's ``models`` can tell."""
        (tmp_path / "config.yaml").write_text("name: go2_to_xbot\nscale: smoke\n")
        runtime = runtime_fingerprint(run_cli.build_config({"scale": "smoke"}))
        now = dict(part.split("=") for part in runtime["models"].split("; "))
        assert set(now) == {"go2.xml", "xbot_l.xml"}  # go2_to_xbot trains both
        old = runtime["models"].replace(now["xbot_l.xml"], "0123456789abcdef")
        artifacts.save_state(tmp_path / RESUME_STATE, {"x": np.zeros(1)}, {"runtime": {**runtime, "models": old}})
        with pytest.raises(ConfigError, match=r"another runtime.*\(model xbot_l.xml: saved sha256 0123456789abcdef, "
                                              rf"now {now['xbot_l.xml']}\)") as refused:
            run_cli.resume(tmp_path)
        assert "go2.xml" not in str(refused.value)  # only the changed model is named

    def test_a_state_saved_before_the_cpu_was_recorded_is_not_refused_for_it(self, tmp_path):
        """States written before ``cpu_isa`` existed lack the key; only keys both hold are compared."""
        runtime = runtime_fingerprint(run_cli.build_config({"scale": "smoke"}))
        runtime.pop("cpu_isa")
        check_runtime(runtime, run_cli.build_config({"scale": "smoke"}), tmp_path)  # no error

    def test_a_resumed_process_takes_the_saved_xla_flags(self, tmp_path, monkeypatch):
        from ptrl_jax.io.xla_flags import configure_from_argv

        artifacts.save_state(tmp_path / RESUME_STATE, {"x": np.zeros(1)},
                             {"runtime": {"xla_flags": "--xla_backend_optimization_level=0"}})
        monkeypatch.delenv("XLA_FLAGS", raising=False)
        configure_from_argv([f"resume={tmp_path}"])
        assert os.environ["XLA_FLAGS"] == "--xla_backend_optimization_level=0"
        monkeypatch.delenv("XLA_FLAGS")
        configure_from_argv(["exp=go2_to_xbot", "scale=cpu"])
        assert "XLA_FLAGS" not in os.environ


class TestHostCpu:
    """``parse_cpuinfo`` on hand-written /proc/cpuinfo texts."""

    CPUINFO = ("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\n"
               "model name\t: AMD EPYC\nflags\t\t: fpu sse2 avx512bw avx2 fma avx sse4_2 avx512f avx512_bf16 "
               "aes\n\nprocessor\t: 1\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 1\n"
               "model name\t: AMD EPYC\nflags\t\t: fpu sse2 avx2 fma avx sse4_2\n\n")

    def test_model_with_family_and_number(self):
        assert parse_cpuinfo(self.CPUINFO)[0] == "AMD EPYC (family 25 model 17)"

    def test_isa_is_the_vector_flags_in_a_fixed_order_others_left_out(self):
        assert parse_cpuinfo(self.CPUINFO)[1] == "sse4_2 avx fma avx2 avx512f avx512bw avx512_bf16"

    def test_only_the_first_processor_is_read(self):
        assert "avx512f" in parse_cpuinfo(self.CPUINFO)[1]  # the second block (no AVX-512) is ignored

    def test_no_flags_line_gives_an_empty_isa(self):
        assert parse_cpuinfo("processor\t: 0\nmodel name\t: Some CPU\n") == ("Some CPU", "")

    def test_empty_text(self):
        assert parse_cpuinfo("") == ("", "")


class TestCtrlC:
    def test_sigint_saves_the_state_and_exits_cleanly(self, smoke_run, tmp_path, capsys):
        """In-process (the compiled smoke program is reused): a SIGINT arrives as soon as the
        first state is saved; the run saves again at the end of that slice and stops."""
        cfg, _ = smoke_run
        cfg = dataclasses.replace(cfg, runs_dir=str(tmp_path))

        def interrupt_when_saved():
            deadline = time.monotonic() + 600
            while time.monotonic() < deadline:
                if list(tmp_path.glob(f"go2_to_xbot/*/{RESUME_STATE}")):
                    os.kill(os.getpid(), signal.SIGINT)
                    return
                time.sleep(0.005)

        handler_before = signal.getsignal(signal.SIGINT)  # SIG_IGN under nohup, for one
        watcher = threading.Thread(target=interrupt_when_saved, daemon=True)
        watcher.start()
        result = run_cli.run(cfg)
        watcher.join()
        assert result["interrupted"], "the run finished before the signal took effect"
        run_dir = result["run_dir"]
        assert run_cli._report_result(result) == 130
        assert f"resume with: python -m ptrl_jax.run resume={run_dir}" in capsys.readouterr().err
        meta = artifacts.read_state_meta(run_dir / RESUME_STATE)
        assert meta["target_iteration"] < cfg.target.ppo.num_iterations
        assert not (run_dir / "report.md").exists() and not (run_dir / "metrics.csv").exists()
        assert signal.getsignal(signal.SIGINT) == handler_before  # our handler is gone again


class TestBadResumeState:
    TEMPLATE = {"params": {"w": jax.ShapeDtypeStruct((3, 2), np.float32)}, "step": jax.ShapeDtypeStruct((), np.int32)}

    def save(self, path, w_shape=(3, 2)):
        tree = {"params": {"w": np.ones(w_shape, np.float32)}, "step": np.int32(4)}
        artifacts.save_state(path, tree, {"note": "test"})

    def test_round_trip(self, tmp_path):
        self.save(tmp_path / "s.npz")
        tree, meta = artifacts.load_state(tmp_path / "s.npz", self.TEMPLATE)
        assert tree["params"]["w"].shape == (3, 2) and int(tree["step"]) == 4 and meta["note"] == "test"

    def test_other_shapes_are_named(self, tmp_path):
        self.save(tmp_path / "s.npz", w_shape=(5, 2))
        with pytest.raises(CheckpointError, match=r"\['params'\]\['w'\] is float32\[5, 2\].*needs float32\[3, 2\]"):
            artifacts.load_state(tmp_path / "s.npz", self.TEMPLATE)

    def test_other_structure_is_named(self, tmp_path):
        artifacts.save_state(tmp_path / "s.npz", {"params": {"v": np.ones(2)}, "step": np.int32(0)}, {})
        with pytest.raises(CheckpointError, match=r"missing \[\"\['params'\]\['w'\]\"\]|missing \['\[.params.\]\[.w.\]'\]"):
            artifacts.load_state(tmp_path / "s.npz", self.TEMPLATE)

    def test_a_state_of_an_older_layout_is_refused_by_name(self, tmp_path):
        import json

        self.save(tmp_path / "s.npz")
        arrays = dict(np.load(tmp_path / "s.npz"))
        meta = json.loads(bytes(arrays["__meta__"]).decode())
        del meta["state_format"]  # as written before the layout was numbered
        arrays["__meta__"] = np.frombuffer(json.dumps(meta).encode(), np.uint8)
        np.savez(tmp_path / "old.npz", **arrays)
        with pytest.raises(CheckpointError, match=r"old.npz has state layout 1, this ptrl_jax writes and reads 2"):
            artifacts.load_state(tmp_path / "old.npz", self.TEMPLATE)

    def test_truncated_file(self, tmp_path):
        self.save(tmp_path / "s.npz")
        data = (tmp_path / "s.npz").read_bytes()
        (tmp_path / "s.npz").write_bytes(data[: len(data) // 2])
        with pytest.raises(CheckpointError, match="unreadable"):
            artifacts.load_state(tmp_path / "s.npz", self.TEMPLATE)

    def test_resume_of_a_folder_without_state(self, tmp_path):
        (tmp_path / "config.yaml").write_text("name: go2_to_xbot\n")
        with pytest.raises(ConfigError, match="no resume_state.npz"):
            run_cli.resume(tmp_path)
        assert run_cli.main([f"resume={tmp_path}"]) == 2


class TestBadPolicyCheckpoint:
    def test_truncated_checkpoint(self, smoke_run, tmp_path):
        _, run_dir = smoke_run
        data = (run_dir / "source.npz").read_bytes()
        (tmp_path / "cut.npz").write_bytes(data[:1000])
        with pytest.raises(CheckpointError, match="unreadable"):
            policy_from_checkpoint(str(tmp_path / "cut.npz"))

    def test_params_of_another_robot_are_refused(self, smoke_run, tmp_path):
        _, run_dir = smoke_run
        go2 = artifacts.load_checkpoint(run_dir / "source.npz")
        xbot = artifacts.load_checkpoint(run_dir / "target_none_seed0.npz")
        # XBot-L weights labelled as Go2: observation sizes 705 vs 45 differ.
        artifacts.save_checkpoint(tmp_path / "mixed.npz", xbot["params"], go2["normalizer"], xbot["frozen"], go2["meta"])
        with pytest.raises(CheckpointError, match=r"actor/layer_0/w.*705.*go2.*45"):
            policy_from_checkpoint(str(tmp_path / "mixed.npz"))

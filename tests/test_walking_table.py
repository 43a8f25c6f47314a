"""Issue 3's per-robot table: the from-scratch presets, the walking-check rows by hand, and the
batch that builds the table (exp=from_scratch)."""

import numpy as np
import pytest

import envs
from envs.biped import BipedEnv
from ptrl_jax import batch
from ptrl_jax.io import artifacts, walking_table
from ptrl_jax.batch import batch_configs, run_batch
from ptrl_jax.io.overrides import ConfigError, load_experiment


class TestFromScratchPresets:
    @pytest.mark.parametrize("robot", envs.robot_names())
    @pytest.mark.parametrize("scale", ["smoke", "cpu", "paper"])
    def test_every_robot_has_one_that_trains_it_alone(self, robot, scale):
        cfg = load_experiment(f"{robot}_from_scratch", [f"scale={scale}"])
        assert list(cfg.targets) == [robot] and cfg.freeze_presets == ("scratch",)
        assert not cfg.trains_source and cfg.freeze_ratio == ()
        ppo = cfg.target.ppo
        assert (ppo.gamma, ppo.gae_lambda, ppo.clip_epsilon, ppo.value_coef) == (0.998, 0.95, 0.2, 1.0)

    def test_each_family_keeps_its_recipe(self):
        for robot in envs.robot_names():
            ppo = load_experiment(f"{robot}_from_scratch").target.ppo
            if envs.family(robot) is BipedEnv:  # humanoid-gym's entropy and epochs, KL target 0.02
                assert (ppo.num_envs, ppo.entropy_coef, ppo.num_epochs, ppo.desired_kl) == (512, 0.001, 2, 0.02)
            else:  # the paper's PPO, forward commands and a closing low-noise phase
                assert (ppo.num_envs, ppo.entropy_coef, ppo.num_epochs, ppo.desired_kl) == (1024, 0.01, 5, 0.01)
                assert ppo.final_noise_iterations > 0
                cmd = load_experiment(f"{robot}_from_scratch").targets[robot].env.commands
                assert cmd.lin_vel_x == (0.0, 1.0)

    def test_the_per_robot_settings_are_the_measured_ones(self):
        def it(robot):
            ppo = load_experiment(f"{robot}_from_scratch").target.ppo
            return ppo.num_iterations, ppo.final_noise_iterations

        assert it("anymal_b") == (120, 20) and it("anymal_c") == (180, 60) and it("go2") == (180, 30)
        assert load_experiment("a1_from_scratch").network.init_noise_std == 1.0
        assert load_experiment("go2_from_scratch").network.init_noise_std == 0.5
        assert it("cassie") == (500, 0) and it("xbot_l") == (700, 0) and it("mit_humanoid") == (800, 0)
        mit = load_experiment("mit_humanoid_from_scratch").targets["mit_humanoid"].env.commands
        assert (mit.lin_vel_x, mit.lin_vel_y) == ((0.0, 0.6), (-0.2, 0.2))  # forward only
        assert load_experiment("cassie_from_scratch").targets["cassie"].env.commands == envs.default_config("cassie").commands

    def test_the_batch_lists_every_robot_once(self):
        configs, settings = batch_configs("from_scratch", {"scale": "smoke"})
        assert settings["table"] == "walking_checks"
        assert sorted(r for cfg in configs.values() for r in cfg.targets) == sorted(envs.robot_names())


def metrics(robot="go2", seeds=2, iterations=12, reward=lambda s, i: i + 10.0 * s):
    return [{"stage": "target", "robot": robot, "preset": "scratch", "seed": s, "iteration": i + 1,
             "env_steps": 100 * (i + 1), "wall_time_s": float(i), "episode_reward": reward(s, i)}
            for s in range(seeds) for i in range(iterations)]


def verdict(name, vx, speed, fell=False, survived=20.0):
    error = abs(speed - vx)
    passed = not fell and error <= 0.15
    return {"check": name, "command": [vx, 0.0, 0.0], "passed": passed,
            "why_not": "" if passed else "off", "fell": fell, "time_survived_s": survived,
            "mean_velocity": [speed, 0.0, 0.0], "forward_speed_error": error}


class TestExperimentRows:
    def test_one_row_per_seed_and_check_with_the_final_reward_of_that_seed(self, tmp_path):
        seen = []

        def checker(path):
            seen.append(path)
            return [verdict("stand", 0.0, 0.01), verdict("walk", 0.3, 0.05)]

        rows = walking_table.experiment_rows("exp", metrics(robot="tron1"), tmp_path, checker, final_window=4,
                                             compile_s=80.0, train_s=1400.0)
        assert seen == [tmp_path / "target_scratch_seed0.npz", tmp_path / "target_scratch_seed1.npz"]
        assert [(r["seed"], r["check"]) for r in rows] == [(0, "stand"), (0, "walk"), (1, "stand"), (1, "walk")]
        # the mean of iterations 8..11 (rewards 8, 9, 10, 11), plus 10 for seed 1
        assert rows[0]["final_reward"] == pytest.approx(9.5) and rows[2]["final_reward"] == pytest.approx(19.5)
        assert rows[0]["env_steps"] == 1200 and rows[0]["iterations"] == 12
        assert [r["passed"] for r in rows] == [True, False, True, False]
        assert rows[1]["speed_error"] == pytest.approx(0.25)

    def test_several_target_robots_read_their_own_checkpoints(self, tmp_path):
        seen = []
        rows = walking_table.experiment_rows(
            "exp", metrics("go2", seeds=1) + metrics("a1", seeds=1), tmp_path,
            lambda p: seen.append(p) or [verdict("walk", 0.5, 0.5)], final_window=2)
        assert seen == [tmp_path / "target_go2_scratch_seed0.npz", tmp_path / "target_a1_scratch_seed0.npz"]
        assert [r["robot"] for r in rows] == ["go2", "a1"]

    def test_a_run_without_scratch_is_refused(self, tmp_path):
        rows = [dict(r, preset="L2") for r in metrics()]
        with pytest.raises(ValueError, match="no metrics for the 'scratch' preset"):
            walking_table.experiment_rows("exp", rows, tmp_path, lambda p: [], final_window=2)

    def test_the_markdown_counts_runs_that_pass_every_check(self, tmp_path):
        checks = iter([[verdict("stand", 0.0, 0.0), verdict("walk", 0.3, 0.2)],
                       [verdict("stand", 0.0, 0.0), verdict("walk", 0.3, 0.1, fell=True, survived=1.5)]])
        rows = walking_table.experiment_rows("exp", metrics("cassie"), tmp_path, lambda p: next(checks), 2)
        text = walking_table.format_markdown(rows, ["a note"])
        assert "**1 of 2 runs pass every check of their family.**" in text
        assert "| cassie | exp | 1 | 1,200 |" in text and "| at 1.50 s |" in text and "- a note" in text
        assert not walking_table.passed_all(rows)


class TestBatch:
    def test_a_batch_without_scratch_runs_is_refused(self, tmp_path):
        spec = tmp_path / "b.yaml"
        spec.write_text("batch: [go2_to_xbot]\ntable: walking_checks\noverrides:\n  freeze_presets: [L2]\n")
        with pytest.raises(ConfigError, match="checks the 'scratch' runs"):
            batch_configs(str(spec), {})

    def test_an_unknown_table_is_refused(self, tmp_path):
        spec = tmp_path / "b.yaml"
        spec.write_text("batch: [go2_to_xbot]\ntable: table5\n")
        with pytest.raises(ConfigError, match="table='table5' is not one of"):
            batch_configs(str(spec), {})

    def test_the_real_checker_loads_the_checkpoint_and_runs_the_family_checks(self, monkeypatch):
        from ptrl_jax import evaluate

        calls = []
        monkeypatch.setattr(evaluate, "policy_from_checkpoint", lambda path: calls.append(path) or {"robot": "a1"})
        monkeypatch.setattr(evaluate, "run_walking_check", lambda policy: [verdict("walk", 0.5, 0.45)])
        assert batch.mjx_walking_check("x/target_scratch_seed0.npz")[0]["passed"]
        assert calls == ["x/target_scratch_seed0.npz"]


def grid_result(vx=0.05, falls=0):
    """``evaluate.run_grid``'s fields that the grid table reads."""
    summary = {"cells": [{}] * 45, "mean_error": {"vx": vx, "vy": 0.02, "yaw": 0.1}, "cells_with_fall": falls,
               "tracked": {"vx": 0.8, "vy": 0.9, "yaw": 0.5}}
    return {"sim": "mujoco", "summary": summary, "pushed": {"fall_rate": 0.025},
            "verdict": {"passed": not falls, "why_not": "fell" if falls else ""}}


class TestGridRows:
    def test_one_row_per_robot_and_seed_of_the_scratch_runs(self, tmp_path):
        seen = []

        def grid_checker(path):
            seen.append(path.name)
            return grid_result()

        rows = walking_table.grid_rows("exp", metrics(robot="tron1"), tmp_path, grid_checker)
        assert seen == ["target_scratch_seed0.npz", "target_scratch_seed1.npz"]
        assert [(r["robot"], r["seed"], r["cells"], r["push_fall_rate"], r["passed"]) for r in rows] == [
            ("tron1", 0, 45, 0.025, True), ("tron1", 1, 45, 0.025, True)]


@pytest.mark.xdist_group("smoke_go2_to_xbot")  # uses the smoke run of test_end_to_end
class TestBatchRun:
    def test_checks_every_scratch_checkpoint_and_writes_the_table(self, tmp_path, smoke_run, monkeypatch):
        """The batch's own logic on the shared smoke run (copied, as in test_transfer_table): the
        checker sees each scratch checkpoint that the run wrote, and the table its verdicts."""
        import shutil

        reference_cfg, reference_dir = smoke_run

        def fake_run(cfg, run_dir, show_progress=None):
            shutil.copytree(reference_dir, run_dir)
            return {"run_dir": run_dir, "interrupted": False, "compile_s": 12.0, "run_s": 3.0,
                    "rows": artifacts.read_metrics_csv(run_dir / "metrics.csv")}

        checked = []

        def checker(path):
            assert path.is_file(), path
            checked.append(path.name)
            return [verdict("stand", 0.0, 0.0), verdict("walk", 0.3, 0.0)]

        gridded = []

        def grid_checker(path):
            assert path.is_file(), path
            gridded.append(path.name)
            return grid_result(vx=0.05 * (len(gridded)), falls=len(gridded) - 1)

        spec = tmp_path / "one.yaml"
        spec.write_text("batch: [go2_to_xbot]\ntable: walking_checks\n")
        result = run_batch(str(spec), {"scale": "smoke", "runs_dir": str(tmp_path / "runs")}, fake_run, checker=checker,
                           grid_checker=grid_checker)
        assert checked == ["target_scratch_seed0.npz", "target_scratch_seed1.npz"] == gridded
        grids = artifacts.read_metrics_csv(result["run_dir"] / "command_grids.csv")
        assert [(r["robot"], r["seed"], r["error_vx"], r["cells_with_fall"]) for r in grids] == [
            ("xbot_l", 0, 0.05, 0), ("xbot_l", 1, 0.1, 1)]
        grid_text = (result["run_dir"] / "command_grids.md").read_text()
        assert "| xbot_l | go2_to_xbot | 1 | mujoco | 45 | 0.100 / 0.020 / 0.100 | 80% / 90% / 50% | 1 | 2.5% | fails: fell |" in grid_text
        assert "**1 of 2 runs meet every goal of the grid.**" in grid_text
        assert result["table_path"] == result["run_dir"] / "walking_checks.md"
        table = artifacts.read_metrics_csv(result["run_dir"] / "walking_checks.csv")
        assert [(r["robot"], r["seed"], r["check"]) for r in table] == [
            ("xbot_l", 0, "stand"), ("xbot_l", 0, "walk"), ("xbot_l", 1, "stand"), ("xbot_l", 1, "walk")]
        metrics_rows = artifacts.read_metrics_csv(result["run_dir"] / "go2_to_xbot" / "metrics.csv")
        seed1 = [r["episode_reward"] for r in metrics_rows if r["stage"] == "target" and r["preset"] == "scratch"
                 and r["seed"] == 1][-reference_cfg.report.final_window:]
        assert table[2]["final_reward"] == pytest.approx(np.mean(seed1), abs=1e-5)
        assert table[0]["compile_s"] == 12.0 and table[0]["train_s"] == 3.0
        text = result["table_path"].read_text()
        assert "**0 of 2 runs pass every check of their family.**" in text

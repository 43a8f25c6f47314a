"""Table IV: time to threshold with transfer and from scratch, by hand; the batch runner."""

import dataclasses
import math

import numpy as np
import pytest

from ptrl_jax.io import artifacts, transfer_table
from ptrl_jax.batch import batch_configs, run_batch
from ptrl_jax.io.overrides import ConfigError, load_experiment

STEPS = [100, 200, 300, 400, 500]
WALL = [1.0, 2.0, 3.0, 4.0, 5.0]


def rows_of(curves: dict) -> list[dict]:
    """metrics.csv-like target rows: {(preset, seed): rewards per iteration}."""
    out = []
    for (preset, seed), rewards in curves.items():
        for i, r in enumerate(rewards):
            out.append({"stage": "target", "robot": "xbot_l", "preset": preset, "seed": seed, "iteration": i,
                        "env_steps": STEPS[i], "wall_time_s": WALL[i], "episode_reward": r})
    return [{"stage": "source", "robot": "go2", "preset": "source", "seed": 0, "iteration": 0,
             "env_steps": 100, "wall_time_s": 1.0, "episode_reward": 0.0}] + out


class TestRobotRow:
    # Scratch finals over the last 2 iterations: seed 0 (3+4)/2 = 3.5, seed 1 (3+5)/2 = 4; mean 3.75.
    # Threshold 0.8 x 3.75 = 3.0. Scratch reaches it at iteration 3 (seed 0) and 3 (seed 1);
    # L2 at iteration 2 (seed 0) and 1 (seed 1).
    CURVES = {
        ("scratch", 0): [0, 1, 2, 3, 4], ("scratch", 1): [0, 1, 2, 3, 5],
        ("L2", 0): [0, 2, 3, 4, 4], ("L2", 1): [1, 3, 3, 3, 3],
    }

    def row(self, curves=None):
        (row,) = transfer_table.experiment_rows("go2_to_xbot", rows_of(curves or self.CURVES), "L2", 0.8, 2)
        return row

    def test_threshold_and_steps(self):
        row = self.row()
        assert (row["source"], row["target"], row["seeds"]) == ("go2", "xbot_l", 2)
        assert row["threshold"] == pytest.approx(3.0)
        assert row["scratch_steps_mean"] == 400 and row["scratch_steps_std"] == 0
        assert row["transfer_steps_mean"] == 250 and row["transfer_steps_std"] == 50  # 300 and 200
        assert row["scratch_wall_s_mean"] == 4.0 and row["transfer_wall_s_mean"] == 2.5

    def test_saving_is_per_paired_seed(self):
        row = self.row()
        # seed 0: 1 - 300/400 = 0.25; seed 1: 1 - 200/400 = 0.5.
        assert row["steps_saved_mean"] == pytest.approx(0.375) and row["steps_saved_std"] == pytest.approx(0.125)
        assert row["wall_saved_mean"] == pytest.approx(0.375)
        assert row["seeds_both_reached"] == 2

    def test_a_seed_that_never_reaches_is_left_out_and_counted(self):
        curves = dict(self.CURVES)
        curves[("L2", 1)] = [0, 0, 0, 0, 0]
        row = self.row(curves)
        assert row["seeds_both_reached"] == 1 and row["steps_saved_mean"] == pytest.approx(0.25)
        assert "not reached" not in transfer_table.format_markdown([row])

    def test_no_seed_reaching_reads_not_reached(self):
        curves = {**self.CURVES, ("L2", 0): [0] * 5, ("L2", 1): [0] * 5}
        row = self.row(curves)
        assert math.isnan(row["steps_saved_mean"]) and row["seeds_both_reached"] == 0
        assert "not reached" in transfer_table.format_markdown([row])

    def test_a_run_from_a_source_checkpoint_names_its_source(self):
        rows = [r for r in rows_of(self.CURVES) if r["stage"] == "target"]  # no source stage
        (row,) = transfer_table.experiment_rows("go2_to_xbot", rows, "L2", 0.8, 2, source="go2")
        assert row["source"] == "go2"

    def test_missing_scratch_is_refused(self):
        curves = {k: v for k, v in self.CURVES.items() if k[0] != "scratch"}
        with pytest.raises(ValueError, match="scratch"):
            self.row(curves)

    def test_the_best_semantic_variant_is_named_and_compared(self):
        curves = {**self.CURVES,
                  ("none@semantic", 0): [0, 0, 3, 3, 3], ("none@semantic", 1): [0, 0, 3, 3, 3],  # 300, 300
                  ("L2@semantic", 0): [3, 3, 3, 3, 3], ("L2@semantic", 1): [0, 3, 3, 3, 3]}    # 100, 200
        row = self.row(curves)
        assert row["semantic_preset"] == "L2@semantic"
        assert row["semantic_steps_mean"] == 150 and row["semantic_steps_std"] == 50
        # seed 0: 1 - 100/400; seed 1: 1 - 200/400
        assert row["semantic_steps_saved_mean"] == pytest.approx(0.625) and row["semantic_seeds_both_reached"] == 2
        assert row["paper_hours_scratch"] == 3.0 and row["paper_saved"] == pytest.approx(1 - 2.5 / 3.0)
        avg = transfer_table.average_row([row])
        assert avg["semantic_steps_saved_mean"] == pytest.approx(0.625)
        md = transfer_table.format_markdown([row])
        assert "(L2@semantic; best of 2 semantic variant(s), chosen after the runs) | +62.5 % ± 12.5 (2/2)" in md
        assert "2.50 h / 3.00 h (17 %)" in md

    def test_a_semantic_preset_named_before_the_runs_is_reported_even_when_another_is_faster(self):
        curves = {**self.CURVES,
                  ("L2@semantic_output", 0): [0, 0, 0, 3, 3], ("L2@semantic_output", 1): [0, 0, 0, 0, 3],  # 400, 500
                  ("L2@semantic_actor", 0): [3, 3, 3, 3, 3], ("L2@semantic_actor", 1): [3, 3, 3, 3, 3]}    # 100, 100
        (row,) = transfer_table.experiment_rows("go2_to_xbot", rows_of(curves), "L2", 0.8, 2,
                                                semantic_preset="L2@semantic_output")
        assert row["semantic_preset"] == "L2@semantic_output" and row["semantic_choice"] == "named before the runs"
        # seed 0: 1 - 400/400 = 0; seed 1: 1 - 500/400 = -0.25
        assert row["semantic_steps_saved_mean"] == pytest.approx(-0.125)
        md = transfer_table.format_markdown([row])
        assert "semantic transfer (preset named before the runs)" in md and "(L2@semantic_output) | -12.5 % ± 12.5" in md

    def test_a_named_semantic_preset_that_did_not_run_reads_not_run(self):
        curves = {**self.CURVES, ("L2@semantic_actor", 0): [3] * 5, ("L2@semantic_actor", 1): [3] * 5}
        (row,) = transfer_table.experiment_rows("go2_to_xbot", rows_of(curves), "L2", 0.8, 2,
                                                semantic_preset="L2@semantic_output")
        assert "semantic_steps_saved_mean" not in row and row["semantic_missing"] == "L2@semantic_output"
        assert "not run (L2@semantic_output, named before the runs)" in transfer_table.format_markdown([row])
        assert "semantic_steps_saved_mean" not in transfer_table.average_row([row])

    def test_a_semantic_variant_that_never_reaches_ranks_last(self):
        curves = {**self.CURVES,
                  ("none@semantic", 0): [0, 0, 0, 3, 3], ("none@semantic", 1): [0, 0, 0, 3, 3],  # 400, 400
                  ("L2@semantic", 0): [3, 3, 3, 3, 3], ("L2@semantic", 1): [0] * 5}              # 100, never
        assert self.row(curves)["semantic_preset"] == "none@semantic"

    def test_average_counts_each_robot_once(self):
        a = {"steps_saved_mean": 0.1, "wall_saved_mean": 0.2}
        b = {"steps_saved_mean": 0.3, "wall_saved_mean": float("nan")}
        avg = transfer_table.average_row([a, b])
        assert avg["steps_saved_mean"] == pytest.approx(0.2) and avg["wall_saved_mean"] == pytest.approx(0.2)


class TestThresholdMetric:
    """A threshold on a reward term (``report.threshold_metric``): a run whose episode reward
    reaches the reward threshold by standing, while its tracking term stays low, does not reach
    the tracking threshold."""

    # Episode reward: scratch walks to 4, "stand" stands at 4 from iteration 1. Tracking term:
    # scratch to 2 (final over 2 iterations: 2), "stand" stays at 1. Threshold 0.8 x final.
    REWARD = {("scratch", 0): [0, 1, 2, 4, 4], ("stand", 0): [0, 4, 4, 4, 4]}
    TRACKING = {("scratch", 0): [0, 0.5, 1, 2, 2], ("stand", 0): [0, 1, 1, 1, 1]}

    def rows(self):
        out = rows_of(self.REWARD)
        tracking = [t for _, ts in self.TRACKING.items() for t in ts]
        out[0]["episode_reward/tracking_lin_vel"] = 0.0
        for r, t in zip(out[1:], tracking):
            r["episode_reward/tracking_lin_vel"] = t
        return out

    def test_table_row_reads_the_metric(self):
        metric = "episode_reward/tracking_lin_vel"
        (by_reward,) = transfer_table.experiment_rows("x", self.rows(), "stand", 0.8, 2)
        (by_tracking,) = transfer_table.experiment_rows("x", self.rows(), "stand", 0.8, 2, metric=metric)
        assert by_reward["threshold"] == pytest.approx(3.2) and by_reward["transfer_steps_mean"] == 200
        assert by_tracking["threshold"] == pytest.approx(1.6) and by_tracking["threshold_metric"] == metric
        assert by_tracking["scratch_steps_mean"] == 400 and math.isnan(by_tracking["transfer_steps_mean"])
        assert by_tracking["transfer_final_reward"] == pytest.approx(4.0)  # finals stay episode rewards

    def test_report_summary_reads_the_metric(self):
        from ptrl_jax.io import summary

        curves = summary.curves_by_preset(self.rows(), "episode_reward/tracking_lin_vel")
        table, threshold = summary.preset_summary(curves, 0.8, 2)
        by_preset = {r["preset"]: r for r in table}
        assert threshold == pytest.approx(1.6)
        assert by_preset["stand"]["seeds_reaching_threshold"] == 0
        assert by_preset["stand"]["final_reward_mean"] == pytest.approx(4.0)
        assert by_preset["scratch"]["steps_to_threshold_mean"] == 400

    def test_a_metric_that_is_not_a_reward_curve_is_refused(self):
        from ptrl_jax.config import ReportConfig

        for bad in ("tracking_lin_vel", "episode_reward/", "loss/value"):
            with pytest.raises(ValueError, match="threshold_metric must be one of \\['episode_reward', 'step_reward'\\]"):
                ReportConfig(threshold_metric=bad)
        ReportConfig(threshold_metric="step_reward/tracking_lin_vel")  # the per-step curve of a term

    def test_an_unknown_reward_term_is_refused_with_the_nearest(self):
        from ptrl_jax.run import check_threshold_metric

        with pytest.raises(ConfigError, match="a1 has no reward term 'tracking_lin_vell'.*tracking_lin_vel'"):
            check_threshold_metric("episode_reward/tracking_lin_vell", {"a1": ("tracking_lin_vel", "torques")})
        check_threshold_metric("episode_reward/torques", {"a1": ("tracking_lin_vel", "torques")})  # a known term passes
        with pytest.raises(ConfigError, match="did you mean 'step_reward/tracking_lin_vel'"):
            check_threshold_metric("step_reward/tracking_lin_vell", {"a1": ("tracking_lin_vel", "torques")})


class TestBatchConfigs:
    @pytest.mark.parametrize("scale", ["smoke", "cpu", "paper"])
    def test_table4_resolves_at_every_scale(self, scale):
        configs, settings = batch_configs("table4", {"scale": scale})
        assert list(configs) == ["go2_to_xbot", "xbot_to_all", "go2_to_a1", "go2_to_anymal_c"]
        assert settings["transfer_preset"] == "L2"
        for cfg in configs.values():
            assert cfg.scale == scale and {"L2", "L2@semantic", "L2@semantic_actor", "L2@semantic_output",
                                           "scratch"} == set(cfg.variants)
            # the preset rule: the semantic column is named by the source's family, before the runs
            rule = {"go2": "L2@semantic_actor", "xbot_l": "L2@semantic_output"}[cfg.source.robot]
            assert cfg.report.semantic_preset == rule
        paper = [r for name in ("go2_to_xbot", "xbot_to_all") for r in configs[name].targets]
        assert len(paper) == 8 == len(set(paper))  # every robot of the paper is a target once
        assert [configs[n].target.robot for n in ("go2_to_a1", "go2_to_anymal_c")] == ["a1", "anymal_c"]

    def test_the_command_line_can_name_the_experiments(self):
        configs, _ = batch_configs("table4", {"scale": "smoke", "batch": "[xbot_to_go2,mit_to_xbot]"})
        assert list(configs) == ["xbot_to_go2", "mit_to_xbot"]
        with pytest.raises(ConfigError, match="unknown experiment 'xbot_to_dog'"):
            batch_configs("table4", {"batch": "[xbot_to_dog]"})

    def test_prefixed_keys_go_to_one_experiment(self):
        configs, _ = batch_configs("table4", {"scale": "smoke", "seeds": "3", "xbot_to_all.target.ppo.num_envs": "8"})
        assert configs["go2_to_xbot"].seeds == configs["xbot_to_all"].seeds == 3
        assert configs["xbot_to_all"].target.ppo.num_envs == 8
        assert configs["go2_to_xbot"].target.ppo.num_envs == 16

    @pytest.mark.parametrize("cli,message", [
        ({"xbot_to_all.target.ppo.num_env": "8"}, "xbot_to_all: .*did you mean 'target.ppo.num_envs'"),
        ({"freeze_presets": "[L1]"}, "compares 'scratch'"),
        ({"scale": "huge"}, "scale must be one of"),
    ])
    def test_bad_input_is_refused_before_anything_runs(self, cli, message, tmp_path):
        with pytest.raises(ConfigError, match=message):
            run_batch("table4", {**cli, "runs_dir": str(tmp_path)}, run=None)
        assert not any(tmp_path.iterdir())

    def test_a_batch_is_not_an_experiment(self):
        with pytest.raises(ConfigError, match="batch of experiments"):
            load_experiment("table4")


@pytest.mark.xdist_group("smoke_go2_to_xbot")  # uses the smoke run of test_end_to_end
class TestBatchRun:
    def test_writes_the_table_from_its_runs(self, tmp_path, smoke_run, monkeypatch):
        """The batch's own logic: it runs each experiment into its folder and builds the table
        from that run's rows. The run itself is the shared smoke run (copied), not a new one:
        run() has its own tests, and a smoke run costs half a minute of the suite."""
        import shutil

        reference_cfg, reference_dir = smoke_run
        calls = []

        def fake_run(cfg, run_dir, show_progress=None):
            calls.append((cfg, run_dir))
            shutil.copytree(reference_dir, run_dir)
            return {"run_dir": run_dir, "interrupted": False,
                    "rows": artifacts.read_metrics_csv(run_dir / "metrics.csv")}

        spec = tmp_path / "one.yaml"
        spec.write_text("batch: [go2_to_xbot]\ntransfer_preset: L1\n")
        result = run_batch(str(spec), {"scale": "smoke", "runs_dir": str(tmp_path / "runs")}, fake_run)
        batch_dir = result["run_dir"]
        ((cfg, run_dir),) = calls
        # the shared smoke run also writes TensorBoard events; the batch's child does not
        assert run_dir == batch_dir / "go2_to_xbot" and cfg == dataclasses.replace(
            reference_cfg, runs_dir=cfg.runs_dir, tensorboard=False)
        assert (batch_dir / "go2_to_xbot" / "report.md").is_file()
        table = artifacts.read_metrics_csv(batch_dir / "table4.csv")
        assert [r["experiment"] for r in table] == ["go2_to_xbot", "average"]
        metrics = artifacts.read_metrics_csv(batch_dir / "go2_to_xbot" / "metrics.csv")
        scratch_final = np.mean([np.mean([r["episode_reward"] for r in metrics if r["preset"] == "scratch"
                                          and r["seed"] == s][-10:]) for s in range(2)])
        assert table[0]["threshold"] == pytest.approx(0.9 * scratch_final, abs=1e-5)
        assert table[0]["transfer_preset"] == "L1"
        md = (batch_dir / "table4.md").read_text()
        assert "| go2 -> xbot_l | 2 |" in md and "(L1) |" in md


class TestRatioTable:
    def row(self, preset, final):
        return {"preset": preset, "final_reward_mean": final, "final_reward_std": 0.0, "auc_mean": final,
                "auc_std": 0.0, "steps_to_threshold_mean": None, "steps_to_threshold_std": None,
                "seeds_reaching_threshold": 0, "seeds": 1}

    def test_presets_stand_in_for_the_ends(self):
        from ptrl_jax.io.summary import format_ratio_table, ratio_table

        table = [self.row("none", 1.0), self.row("L1+L2", 2.0), self.row("scratch", 3.0), self.row("rho0.5", 4.0)]
        rows = ratio_table(table)
        assert [(r["rho"], r["preset"]) for r in rows] == [(0.0, "none"), (0.5, "rho0.5"), (1.0, "L1+L2")]
        text = format_ratio_table(rows, "x.png")
        assert "| 0 (none) | 1.000" in text and "| 0.5 | 4.000" in text and "| 1 (L1+L2) | 2.000" in text

    def test_a_listed_end_is_not_doubled_and_no_ratios_means_no_table(self):
        from ptrl_jax.io.summary import ratio_table

        assert [r["preset"] for r in ratio_table([self.row("none", 1.0), self.row("rho0", 1.5)])] == ["rho0"]
        assert ratio_table([self.row("none", 1.0), self.row("L2", 2.0)]) == []

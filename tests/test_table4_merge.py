"""``python -m ptrl_jax.table4``: Table IV rebuilt from several finished runs, paired by seed, by hand."""

import math

import pytest
import yaml

from ptrl_jax import table4
from ptrl_jax.io import artifacts
from ptrl_jax.io.overrides import ConfigError

STEPS = [100, 200, 300, 400, 500]
PPO = {"num_envs": 4, "unroll_length": 25, "num_iterations": 5}


def make_run(path, curves, seed=0, knee="axis", ppo=PPO, source_checkpoint="", report=None, source=None):
    """A finished run folder: config.yaml and metrics.csv with ``curves``
    ({(preset, seed index): reward per iteration}) as the target rows, go2 -> anymal_b."""
    path.mkdir(parents=True)
    seeds = 1 + max(k for _, k in curves)
    cfg = {"name": path.parent.name, "seed": seed, "seeds": seeds, "source_checkpoint": source_checkpoint,
           "source": {"robot": "go2", **(source or {})}, "target": {"robot": "anymal_b", "ppo": dict(ppo), "env": {"kp": 80.0}},
           "transfer": {"mode": "paper", "knee": knee, "noise_std": 0.5},
           "report": {"threshold_metric": "episode_reward", "threshold_fraction": 0.8, "final_window": 2,
                      **(report or {})}}
    (path / "config.yaml").write_text(yaml.safe_dump(cfg))
    rows = [{"stage": "target", "robot": "anymal_b", "preset": p, "seed": k, "iteration": i, "env_steps": STEPS[i],
             "wall_time_s": float(i), "episode_reward": r} for (p, k), rew in curves.items() for i, r in enumerate(rew)]
    artifacts.write_metrics_csv(path / "metrics.csv", rows)
    return path


# Scratch finals over the last 2 iterations: (3+4)/2 = 3.5 and (3+5)/2 = 4, mean 3.75, threshold
# 0.8 x 3.75 = 3.0: scratch reaches it at 400 env steps on both seeds.
SCRATCH = {("scratch", 0): [0, 1, 2, 3, 4], ("scratch", 1): [0, 1, 2, 3, 5]}


class TestMergedRuns:
    def test_a_variant_of_another_run_is_paired_with_scratch_seed_by_seed(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2@semantic_actor", 0): [0, 3, 3, 3, 3],
                                            ("L2@semantic_actor", 1): [0, 0, 3, 3, 3]}, knee="flexion")
        b = make_run(tmp_path / "b" / "1", {("L2@semantic_actor", 0): [0, 0, 0, 0, 3],
                                            ("L2@semantic_actor", 1): [0, 0, 0, 3, 3]}, knee="axis")
        result = table4.build([a, b])
        (row,) = result["table"]
        assert row["threshold"] == pytest.approx(3.0) and not row["transfer_ran"]
        # flexion: 200 and 300 against 400: saved 0.5 and 0.25
        assert row["semantic_preset"] == "L2@semantic_actor [knee=flexion]"
        assert row["semantic_steps_saved_mean"] == pytest.approx(0.375)
        (variants,) = result["variants"]
        by = {v["preset"]: v for v in variants}
        assert list(by) == ["scratch", "L2@semantic_actor [knee=axis]", "L2@semantic_actor [knee=flexion]"]
        axis = by["L2@semantic_actor [knee=axis]"]
        # axis: 500 and 400 against 400: saved -0.25 and 0
        assert axis["steps_per_seed"] == [500.0, 400.0]
        assert axis["steps_saved_mean"] == pytest.approx(-0.125) and axis["steps_saved_std"] == pytest.approx(0.125)
        assert math.isnan(by["scratch"]["steps_saved_mean"])
        assert "not run (L2)" in result["markdown"] and "-12.5 % ± 12.5 (2/2)" in result["markdown"]

    def test_the_semantic_column_takes_the_preset_the_first_run_names(self, tmp_path):
        curves = {**SCRATCH, ("L2@semantic_actor", 0): [3] * 5, ("L2@semantic_actor", 1): [3] * 5,
                  ("L2@semantic_output", 0): [0, 0, 0, 0, 3], ("L2@semantic_output", 1): [0, 0, 0, 3, 3]}
        run = make_run(tmp_path / "a" / "1", curves, report={"semantic_preset": "L2@semantic_output"})
        (row,) = table4.build([run])["table"]
        # named: 500 and 400 against 400: saved -0.25 and 0, though semantic_actor saved 0.75 on both
        assert row["semantic_preset"] == "L2@semantic_output"
        assert row["semantic_steps_saved_mean"] == pytest.approx(-0.125)
        (best,) = table4.build([run], semantic="best")["table"]
        assert best["semantic_preset"] == "L2@semantic_actor" and best["semantic_steps_saved_mean"] == pytest.approx(0.75)
        assert "chosen after the runs" in table4.build([run], semantic="best")["markdown"]

    def test_variants_from_two_sources_carry_the_source_settings_that_differ(self, tmp_path):
        """One target stage, two sources (one trained twice as long): the same variant and seed
        in both runs is two variants, told apart by the source settings; scratch is one."""
        short, long = ({"ppo": {"num_iterations": n, "num_envs": 512}} for n in (700, 1400))
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2@semantic_output", 0): [0, 0, 0, 0, 3],
                                            ("L2", 0): [0, 0, 0, 3, 3]}, source=short,
                     report={"semantic_preset": "L2@semantic_output"})
        b = make_run(tmp_path / "b" / "1", {("L2@semantic_output", 0): [0, 3, 3, 3, 3]}, source=long)
        (variants,) = table4.build([a, b], semantic="best")["variants"]
        by = {v["preset"]: v for v in variants}
        # L2 ran from one source only, so it keeps its name, and the paper's column finds it.
        assert set(by) == {"scratch", "L2", "L2@semantic_output [source.ppo.num_iterations=700]",
                           "L2@semantic_output [source.ppo.num_iterations=1400]"}
        # against scratch's 400 steps on seed 0: 500 (saved -0.25) and 200 (saved 0.5)
        assert by["L2@semantic_output [source.ppo.num_iterations=700]"]["steps_per_seed"][0] == 500.0
        assert by["L2@semantic_output [source.ppo.num_iterations=1400]"]["steps_saved_mean"] == pytest.approx(0.5)
        # The rule names the bare variant, which now matches two: the refusal names one to give.
        with pytest.raises(ConfigError, match=r"matches 2 variants.*semantic='L2@semantic_output \[source"):
            table4.build([a, b])
        (row,) = table4.build([a, b], semantic="L2@semantic_output [source.ppo.num_iterations=1400]")["table"]
        assert row["semantic_preset"] == "L2@semantic_output [source.ppo.num_iterations=1400]"
        assert row["semantic_steps_saved_mean"] == pytest.approx(0.5)
        assert row["transfer_ran"] and row["steps_saved_mean"] == pytest.approx(0.0)  # L2: 400 against 400

    def test_a_loaded_source_has_the_settings_of_the_run_that_trained_it(self, tmp_path):
        long = {"ppo": {"num_iterations": 1400}}
        trained = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2@semantic_output", 0): [0, 3, 3, 3, 3]}, source=long)
        (trained / "source.npz").write_bytes(b"")
        # the loading run's config names the preset's 700 iterations, but its source is the 1400 one
        loaded = make_run(tmp_path / "b" / "1", {("L2", 0): [0, 0, 0, 3, 3]}, source={"ppo": {"num_iterations": 700}},
                          source_checkpoint=str(trained / "source.npz"))
        other = make_run(tmp_path / "c" / "1", {("L2@semantic_output", 0): [0, 0, 0, 0, 3]},
                         source={"ppo": {"num_iterations": 700}})
        (variants,) = table4.build([trained, loaded, other], semantic="best")["variants"]
        assert {v["preset"] for v in variants} == {
            "scratch", "L2", "L2@semantic_output [source.ppo.num_iterations=1400]",
            "L2@semantic_output [source.ppo.num_iterations=700]"}
        # and a run that trains no source has no source to tell apart
        scratch_only = make_run(tmp_path / "d" / "1", {("scratch", 0): [0, 1, 2, 3, 4]}, seed=2,
                                source={"ppo": {"num_iterations": 350}})
        (variants,) = table4.build([loaded, scratch_only], semantic="best")["variants"]
        assert {v["preset"] for v in variants} == {"scratch", "L2"}

    def test_runs_on_one_source_setting_keep_their_names(self, tmp_path):
        same = {"ppo": {"num_iterations": 700}}
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2", 0): [0, 0, 0, 3, 3]}, source=same)
        b = make_run(tmp_path / "b" / "1", {("L2@semantic_output", 0): [0, 3, 3, 3, 3]}, seed=1, source=same)
        (variants,) = table4.build([a, b], semantic="best")["variants"]
        assert {v["preset"] for v in variants} == {"scratch", "L2", "L2@semantic_output"}

    def test_a_semantic_preset_that_is_not_a_semantic_variant_is_refused(self, tmp_path):
        run = make_run(tmp_path / "a" / "1", SCRATCH)
        with pytest.raises(ConfigError, match="semantic='L2'.*semantic variant"):
            table4.build([run], semantic="L2")
        with pytest.raises(ConfigError, match="unknown transfer mode 'semantik'"):
            table4.build([run], semantic="L2@semantik")

    def test_a_setting_an_older_run_lacks_reads_as_its_default(self, tmp_path):
        """A run from before ``transfer.critic_warmup`` existed ran without a warm-up: its
        variant is labelled with the default, 0, beside the run that set it."""
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2@semantic_actor", 0): [0, 3, 3, 3, 3]})
        b = make_run(tmp_path / "b" / "1", {("L2@semantic_actor", 0): [0, 0, 3, 3, 3]})
        cfg = yaml.safe_load((b / "config.yaml").read_text())
        cfg["transfer"]["critic_warmup"] = 10
        (b / "config.yaml").write_text(yaml.safe_dump(cfg))
        (variants,) = table4.build([a, b])["variants"]
        assert [v["preset"] for v in variants] == [
            "scratch", "L2@semantic_actor [critic_warmup=0]", "L2@semantic_actor [critic_warmup=10]"]

    def test_seed_roots_are_seeds_of_their_own(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("none@semantic", 0): [0, 3, 3, 3, 3],
                                            ("none@semantic", 1): [0, 3, 3, 3, 3]})
        b = make_run(tmp_path / "b" / "1", {("scratch", 0): [0, 0, 0, 3, 4],
                                            ("none@semantic", 0): [3, 3, 3, 3, 3]}, seed=1)
        (variants,) = table4.build([a, b])["variants"]
        scratch, sem = variants
        assert scratch["seeds"] == 3 and sem["seeds"] == 3
        # the threshold now averages three scratch seeds: 0.8 x (3.5 + 4 + 3.5) / 3
        assert scratch["threshold"] == pytest.approx(0.8 * 11 / 3)
        # per seed (0,0), (0,1), (1,0): 400/400/400 for scratch, 200/200/100 for the variant
        assert sem["steps_per_seed"] == [200.0, 200.0, 100.0]
        assert sem["steps_saved_mean"] == pytest.approx((0.5 + 0.5 + 0.75) / 3)

    def test_a_variant_with_fewer_seeds_pairs_only_with_its_own(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH})
        b = make_run(tmp_path / "b" / "1", {("rho0.5@semantic", 0): [0, 0, 3, 3, 3]})  # seed 0 only: 300
        (variants,) = table4.build([a, b])["variants"]
        sem = variants[1]
        # paired with scratch seed 0 alone (400): saved 0.25 with no spread, 1 seed both reached
        assert sem["seeds"] == 1 and sem["seeds_both_reached"] == 1
        assert sem["steps_saved_mean"] == pytest.approx(0.25) and sem["steps_saved_std"] == 0

    def test_the_same_variant_and_seed_in_two_runs_is_refused(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH})
        b = make_run(tmp_path / "b" / "1", {("scratch", 0): [0, 0, 0, 3, 4]})
        with pytest.raises(ConfigError, match=r"'scratch' seed 0 of seed root 0 is in both"):
            table4.build([a, b])

    def test_runs_that_train_the_target_differently_are_refused(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH})
        b = make_run(tmp_path / "b" / "1", {("L2", 0): [0, 3, 3, 3, 3]}, ppo={**PPO, "num_envs": 8})
        with pytest.raises(ConfigError, match=r"target.ppo.num_envs: 8 against 4"):
            table4.build([a, b])

    def test_a_group_without_scratch_is_refused(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {("L2", 0): [0, 3, 3, 3, 3]})
        with pytest.raises(ConfigError, match="scratch"):
            table4.build([a])

    def test_a_folder_that_is_not_a_run_is_refused(self, tmp_path):
        (tmp_path / "empty").mkdir()
        with pytest.raises(ConfigError, match="has no config.yaml or metrics.csv"):
            table4.build([tmp_path / "empty"])

    def test_an_unknown_metric_is_refused(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH})
        with pytest.raises(ConfigError, match="no such column"):
            table4.build([a], metric="step_reward/tracking_lin_vel")


class TestCommandLine:
    def test_writes_the_tables_and_keeps_what_is_there(self, tmp_path, capsys):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2", 0): [0, 3, 3, 3, 3], ("L2", 1): [0, 3, 3, 3, 3]})
        out = tmp_path / "table"
        assert table4.main([f"runs=[{a}]", f"out={out}"]) == 0
        assert "| go2 -> anymal_b | 2 |" in capsys.readouterr().out
        rows = artifacts.read_metrics_csv(out / "table4.csv")
        assert rows[0]["steps_saved_mean"] == pytest.approx(0.5) and rows[-1]["experiment"] == "average"
        variants = artifacts.read_metrics_csv(out / "variants.csv")
        assert [v["preset"] for v in variants] == ["scratch", "L2"]
        before = (out / "table4.md").read_text()
        assert table4.main([f"runs=[{a}]", f"out={out}"]) == 2
        assert "already holds table4.md" in capsys.readouterr().err
        assert (out / "table4.md").read_text() == before

    def test_unknown_keys_are_refused(self, capsys):
        assert table4.main(["runs=[x]", "thresold=0.5"]) == 2
        assert "unknown argument(s) ['thresold']" in capsys.readouterr().err


class TestFreezeRatioFromMergedRuns:
    """A freeze-ratio sweep run in another program than its scratch and whole-layer variants."""

    def runs(self, tmp_path):
        a = make_run(tmp_path / "a" / "1", {**SCRATCH, ("L2@semantic_actor", 0): [0, 3, 3, 3, 3],
                                            ("L2@semantic_actor", 1): [0, 0, 3, 3, 3], ("L2", 0): [3] * 5,
                                            ("L2", 1): [3] * 5})
        b = make_run(tmp_path / "b" / "1", {("rho0@semantic_actor", 0): [0, 0, 0, 3, 3],
                                            ("rho0@semantic_actor", 1): [0, 0, 0, 3, 3],
                                            ("rho1@semantic_actor", 0): [0, 0, 0, 0, 3],
                                            ("rho1@semantic_actor", 1): [0, 0, 0, 0, 3]})
        return a, b

    def test_the_curve_holds_the_mode_s_variants_at_their_frozen_share(self, tmp_path):
        result = table4.build(list(self.runs(tmp_path)))
        ((scratch, (curve,), png),) = result["ratios"]  # the paper's L2 alone makes no curve
        assert scratch["preset"] == "scratch" and curve["mode"] == "semantic_actor" and curve["label"] == ""
        assert png == ["freeze_ratio_go2_anymal_b_semantic_actor.png"]
        points = [(p["preset"], round(p["share"], 4), p["ratio"], p["steps_per_seed"]) for p in curve["points"]]
        # threshold 3.0, scratch at 400 on both seeds
        assert points == [("rho0@semantic_actor", 0.0, True, [400.0, 400.0]),
                          ("L2@semantic_actor", 0.2003, False, [200.0, 300.0]),
                          ("rho1@semantic_actor", 1.0, True, [500.0, 500.0])]
        assert [p["steps_saved_mean"] for p in curve["points"]] == pytest.approx([0.0, 0.375, -0.25])
        text = result["markdown"]
        assert "## go2 -> anymal_b: freeze ratio, semantic_actor transfer" in text
        assert "| L2@semantic_actor | 0.20 | 0.00 ± 0.00 M | +37.5 % ± 12.5 (2/2) | 3.00 ± 0.00 |" in text
        assert "| rho1@semantic_actor | 1.00 | 0.00 ± 0.00 M | -25.0 % ± 0.0 (2/2) | 1.50 ± 0.00 |" in text
        assert "![freeze ratio]" not in text  # figures only where out= draws them

    def test_out_draws_the_curve_and_keeps_an_existing_one(self, tmp_path):
        result = table4.build(list(self.runs(tmp_path)))
        out = tmp_path / "out"
        table4.write(out, result)
        png = out / "freeze_ratio_go2_anymal_b_semantic_actor.png"
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert "![freeze ratio](freeze_ratio_go2_anymal_b_semantic_actor.png)" in (out / "table4.md").read_text()
        for name in table4.OUTPUTS:
            (out / name).unlink()
        before = png.read_bytes()
        with pytest.raises(ConfigError, match="already holds freeze_ratio_go2_anymal_b_semantic_actor.png; pass overwrite"):
            table4.write(out, result)
        assert png.read_bytes() == before and not (out / "table4.md").exists()

    def test_no_ratio_variant_no_curve(self, tmp_path):
        a, _ = self.runs(tmp_path)
        result = table4.build([a])
        assert result["ratios"] == [] and "freeze ratio" not in result["markdown"]

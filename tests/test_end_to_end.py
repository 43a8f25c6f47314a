"""``scale=smoke`` end to end: one compiled program, every output written and consistent."""

import csv
import json

import numpy as np
import pytest
import yaml

from ptrl_jax.io import artifacts

# One xdist worker runs every test of the shared smoke run (tests/conftest.py: smoke_run).
pytestmark = pytest.mark.xdist_group("smoke_go2_to_xbot")

PRESETS = ("none", "L1", "L2", "L1+L2", "scratch", "none@semantic", "L2@semantic")
RATIOS = ("rho0.25", "rho0.5", "rho0.75")  # go2_to_xbot.yaml's freeze_ratio
VARIANTS = PRESETS + RATIOS


class TestSmokeRunOutputs:
    def test_files(self, smoke_run):
        cfg, run_dir = smoke_run
        names = {p.name for p in run_dir.iterdir()}
        expected = {"config.yaml", "metrics.csv", "curves.png", "freeze_ratio.png", "report.md", "source.npz"}
        assert "## Zero-shot" in (run_dir / "report.md").read_text()
        expected |= {f"target_{p}_seed{s}.npz" for p in VARIANTS for s in range(cfg.seeds)}
        assert cfg.variants == VARIANTS and cfg.seeds == 2
        assert expected <= names, expected - names
        for png in ("curves.png", "freeze_ratio.png"):
            assert (run_dir / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        resolved = yaml.safe_load((run_dir / "config.yaml").read_text())
        assert resolved["target"]["robot"] == "xbot_l" and resolved["scale"] == "smoke"
        # checkpoint_every=1: one iteration per call, so each wall time is a measured stamp
        assert "Progress was off" not in (run_dir / "report.md").read_text()

    def test_report_gives_the_source_walking_check(self, smoke_run):
        from ptrl_jax import evaluate
        from ptrl_jax.io.outputs import format_source_checks

        cfg, run_dir = smoke_run
        policy = evaluate.policy_from_checkpoint(str(run_dir / "source.npz"))
        verdicts = evaluate.run_walking_check(policy, sim="mujoco", seconds=cfg.report.zero_shot_seconds)
        source_line = next(line for line in (run_dir / "report.md").read_text().splitlines()
                           if line.startswith("- Source go2:"))
        assert source_line.endswith("; " + format_source_checks(verdicts, cfg.report.zero_shot_seconds))

    def test_metrics_rows_and_columns(self, smoke_run):
        cfg, run_dir = smoke_run
        rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
        n_src, n_tgt = cfg.source.ppo.num_iterations, cfg.target.ppo.num_iterations
        assert len(rows) == n_src + len(VARIANTS) * cfg.seeds * n_tgt
        cols = set(rows[0])
        for c in ("stage", "preset", "seed", "iteration", "env_steps", "wall_time_s", "episode_reward",
                  "episode_length", "kl", "learning_rate", "noise_std", "episode_reward/tracking_lin_vel", "episode_reward/joint_pos",
                  "step_reward/tracking_lin_vel", "step_reward/joint_pos"):
            assert c in cols, c
        for r in rows:
            assert np.isfinite(float(r["wall_time_s"])) and np.isfinite(float(r["kl"]))

    def test_tensorboard_events_hold_the_metrics(self, smoke_run):
        from test_tensorboard import read_scalars

        cfg, run_dir = smoke_run
        rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
        folders = {p.name for p in (run_dir / "tensorboard").iterdir()}
        assert len(folders) == 1 + len(VARIANTS) * cfg.seeds and "target_xbot_l_L2_at_semantic_seed1" in folders
        got = read_scalars(run_dir / "tensorboard" / "target_xbot_l_L2_seed0")["episode_reward"]
        want = [(int(r["env_steps"]), float(r["episode_reward"])) for r in rows
                if r["stage"] == "target" and r["preset"] == "L2" and r["seed"] == "0"]
        assert [(s, v) for s, v, _ in got] == [(s, pytest.approx(v)) for s, v in want]

    def test_freezing_holds_inside_the_program(self, smoke_run):
        _, run_dir = smoke_run
        src = artifacts.load_checkpoint(run_dir / "source.npz")["params"]["actor"]
        both = artifacts.load_checkpoint(run_dir / "target_L1+L2_seed0.npz")
        l2 = artifacts.load_checkpoint(run_dir / "target_L2_seed0.npz")["params"]["actor"]
        none = artifacts.load_checkpoint(run_dir / "target_none_seed0.npz")["params"]["actor"]
        scratch = artifacts.load_checkpoint(run_dir / "target_scratch_seed0.npz")["params"]["actor"]
        for layer in ("layer_1", "layer_2"):
            assert np.array_equal(both["params"]["actor"][layer]["w"], src[layer]["w"])  # transferred, frozen
            assert both["frozen"]["actor"][layer]["w"].all()
            assert not np.array_equal(scratch[layer]["w"], src[layer]["w"])  # no transfer
        assert np.array_equal(l2["layer_2"]["w"], src["layer_2"]["w"])
        assert not np.array_equal(l2["layer_1"]["w"], src["layer_1"]["w"])  # fine-tuned
        assert not np.array_equal(none["layer_1"]["w"], src["layer_1"]["w"])
        assert both["meta"]["robot"] == "xbot_l" and both["meta"]["preset"] == "L1+L2"
        assert set(both["normalizer"]) == {"state", "privileged_state"}

    def test_semantic_variants_carry_the_source_and_freeze_as_the_paper_does(self, smoke_run):
        _, run_dir = smoke_run
        src = artifacts.load_checkpoint(run_dir / "source.npz")["params"]
        l2 = artifacts.load_checkpoint(run_dir / "target_L2@semantic_seed0.npz")
        none = artifacts.load_checkpoint(run_dir / "target_none@semantic_seed1.npz")["params"]
        scratch = artifacts.load_checkpoint(run_dir / "target_scratch_seed1.npz")["params"]
        assert np.array_equal(l2["params"]["actor"]["layer_2"]["w"], src["actor"]["layer_2"]["w"])  # frozen
        assert l2["frozen"]["actor"]["layer_2"]["w"].all() and not l2["frozen"]["actor"]["layer_0"]["w"].any()
        assert l2["meta"]["preset"] == "L2@semantic"
        # The critic's hidden layers start from the source's (the paper's transfer leaves them fresh):
        # after two iterations of fine-tuning they are still near the source's, scratch's are not.
        near = lambda p: float(np.abs(p["critic"]["layer_1"]["w"] - src["critic"]["layer_1"]["w"]).max())  # noqa: E731
        assert near(none) < 0.05 < near(scratch)

    def test_freeze_ratio_freezes_the_first_units(self, smoke_run):
        _, run_dir = smoke_run
        src = artifacts.load_checkpoint(run_dir / "source.npz")["params"]["actor"]
        for name, rho in (("rho0.25", 0.25), ("rho0.5", 0.5), ("rho0.75", 0.75)):
            ckpt = artifacts.load_checkpoint(run_dir / f"target_{name}_seed1.npz")
            for layer, units in (("layer_1", 256), ("layer_2", 128)):
                k = int(rho * units)
                w, frozen = ckpt["params"]["actor"][layer]["w"], ckpt["frozen"]["actor"][layer]["w"]
                assert frozen[:, :k].all() and not frozen[:, k:].any(), (name, layer)
                assert np.array_equal(w[:, :k], src[layer]["w"][:, :k]), (name, layer)  # kept
                assert not np.array_equal(w[:, k:], src[layer]["w"][:, k:]), (name, layer)  # fine-tuned
            assert ckpt["meta"]["preset"] == name

    def test_report_agrees_with_metrics(self, smoke_run):
        cfg, run_dir = smoke_run
        rows = artifacts.read_metrics_csv(run_dir / "metrics.csv")
        report = (run_dir / "report.md").read_text()
        ratio_section = report.split("## Freeze ratio", 1)[1]
        for name in RATIOS:
            finals = [np.mean([r["episode_reward"] for r in rows if r["stage"] == "target" and r["preset"] == name
                               and r["seed"] == s][-cfg.report.final_window:]) for s in range(cfg.seeds)]
            line = next(l for l in ratio_section.splitlines() if l.startswith(f"| {name[3:]} |"))
            assert f"{np.mean(finals):.3f} ± {np.std(finals):.3f}" in line, (name, line)
        for preset in VARIANTS:
            finals = []
            for s in range(cfg.seeds):
                curve = [r["episode_reward"] for r in rows if r["stage"] == "target" and r["preset"] == preset and r["seed"] == s]
                finals.append(np.mean(curve[-cfg.report.final_window:]))
            line = next(l for l in report.splitlines() if l.startswith(f"| {preset} |"))
            assert f"{np.mean(finals):.3f}" in line, (preset, line)


class TestCommandGridOfTheSmokeSource:
    def test_grid_with_pushes_writes_its_table_and_heat_map(self, smoke_run, tmp_path, capsys):
        """The CLI's grid (MuJoCo C, 3 commands, pushes every 0.1 s, 2 push seeds) on the smoke
        run's Go2 source: every cell and pushed rollout is accounted for in the files."""
        from ptrl_jax import evaluate

        _, run_dir = smoke_run
        out = tmp_path / "grid"
        status = evaluate.main([f"ckpt={run_dir}/source.npz", "grid=true", "sim=mujoco", "seconds=0.4",
                                "grid_vx=[0,0.5]", "grid_vy=[0]", "grid_yaw=[0,0.5]", "pushes=true",
                                "push_seeds=2", "push_interval=0.1", f"out={out}"])
        assert status in (0, 1)
        result = json.loads((out / "grid.json").read_text())
        assert [c["command"] for c in result["summary"]["cells"]] == [[0, 0, 0], [0, 0, 0.5], [0.5, 0, 0], [0.5, 0, 0.5]]
        assert result["pushed"]["rollouts"] == 8 and len(result["pushed"]["cells"]) == 4
        assert [v["check"] for v in result["walking_check"]] == ["walk"]  # Go2's check is the (0.5, 0, 0) cell
        assert status == (0 if result["verdict"]["passed"] else 1)
        assert (out / "grid.png").stat().st_size > 10_000
        rows = (out / "grid.csv").read_text().splitlines()
        assert len(rows) == 5 and rows[0].endswith("push_fall_rate")
        assert "Walking check 'walk'" in (out / "grid.md").read_text() and "wrote" in capsys.readouterr().out


class TestSourceCheckLine:
    """The report's one-line verdict on the source, on hand-made verdicts."""

    @staticmethod
    def verdict(check, vx, speed, passed):
        return {"check": check, "command": [vx, 0.0, 0.0], "passed": passed, "time_survived_s": 20.0,
                "mean_velocity": [speed, 0.0, 0.0]}

    def test_passes_only_when_every_check_passes(self):
        from ptrl_jax.io.outputs import format_source_checks

        stand, walk = self.verdict("stand", 0.0, 0.004, True), self.verdict("walk", 0.3, 0.074, False)
        assert format_source_checks([stand, walk]) == (
            "the source FAILS its walking check (MuJoCo C, mean action, 20 s per command: "
            "stand vx 0: 20.0 s, 0.00 m/s, pass; walk vx 0.3: 20.0 s, 0.07 m/s, fail)")
        walk["passed"] = True
        assert format_source_checks([stand, walk], seconds=1.0).startswith(
            "the source passes its walking check (MuJoCo C, mean action, 1 s per command: ")

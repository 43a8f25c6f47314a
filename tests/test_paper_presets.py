"""Every transfer preset of the paper runs at ``scale=smoke``, batched: ``xbot_to_all`` trains
XBot-L once and fine-tunes the seven other robots in one compiled program (so it also covers the
seven ``xbot_to_<robot>`` presets' source and targets, whose configs tests/test_config.py checks
resolve to the same stages), and ``mit_to_xbot`` is the one other source (marked slow).
go2_to_xbot has its own tests (test_end_to_end.py)."""

import csv

import jax
import numpy as np
import pytest

import envs
from ptrl_jax.io import artifacts
from ptrl_jax import run as run_cli
from ptrl_jax.io.overrides import load_experiment

PRESETS = ("none", "L1", "L2", "L1+L2", "scratch")


def smoke(exp, tmp_path_factory):
    runs = tmp_path_factory.mktemp(exp)
    cfg = load_experiment(exp, ["scale=smoke", f"runs_dir={runs}"])
    return cfg, run_cli.run(cfg)["run_dir"]


def check_transfer(run_dir, target_file_prefix, target_robot):
    """L1+L2 keeps the source's hidden layers bitwise; scratch does not have them; the input and
    output layers take the target's sizes."""
    src = artifacts.load_checkpoint(run_dir / "source.npz")["params"]["actor"]
    both = artifacts.load_checkpoint(run_dir / f"{target_file_prefix}L1+L2_seed0.npz")
    scratch = artifacts.load_checkpoint(run_dir / f"{target_file_prefix}scratch_seed0.npz")["params"]["actor"]
    for layer in ("layer_1", "layer_2"):
        assert np.array_equal(both["params"]["actor"][layer]["w"], src[layer]["w"]), (target_robot, layer)
        assert not np.array_equal(scratch[layer]["w"], src[layer]["w"]), (target_robot, layer)
    env = envs.make(target_robot)
    # eval_shape, not brax's observation_size: that runs a reset eagerly, op by op (~20 s each).
    obs_size = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs["state"].shape[0]
    assert both["params"]["actor"]["layer_0"]["w"].shape[0] == obs_size
    assert both["params"]["actor"]["layer_3"]["w"].shape[1] == env.action_size
    assert both["meta"]["robot"] == target_robot


# The costliest test program: one trainer per robot in one program, about 4 min of one core to
# trace and compile with all eight (MuJoCo C's engine, AMD EPYC, 2026-12-02). The default suite
# runs it with the target robots that no other suite program trains (Go2 and XBot-L train in the
# go2_to_xbot smoke run, A1 in the two-device and transfer-tool tests; the ANYmals are the same
# quadruped env on other models, and step in the registry walk and the engine test): XBot-L and
# the three other bipeds. `-m slow` runs the preset whole. tests/conftest.py hands this group out first, so one xdist worker builds it while the
# other runs the rest.
SUITE_TARGETS = ("cassie", "tron1")  # besides the preset's target, the MIT Humanoid


@pytest.mark.parametrize("targets", [pytest.param("suite", marks=pytest.mark.xdist_group("xbot_to_all")),
                                     pytest.param("all", marks=[pytest.mark.slow, pytest.mark.xdist_group("xbot_to_all")])],
                         scope="class")
class TestXBotToAll:
    @pytest.fixture(scope="class")
    def xbot_to_all(self, tmp_path_factory, targets):
        extra = [f"extra_targets=[{','.join(SUITE_TARGETS)}]"] if targets == "suite" else []
        runs = tmp_path_factory.mktemp("xbot_to_all")
        cfg = load_experiment("xbot_to_all", ["scale=smoke", f"runs_dir={runs}", *extra])
        return cfg, run_cli.run(cfg)["run_dir"]

    def test_every_target_robot_leaves_its_checkpoints_curves_and_report(self, xbot_to_all, targets):
        cfg, run_dir = xbot_to_all
        names = {p.name for p in run_dir.iterdir()}
        assert len(cfg.targets) == (7 if targets == "all" else 1 + len(SUITE_TARGETS))
        for robot in cfg.targets:
            expected = {f"target_{robot}_{p}_seed0.npz" for p in PRESETS} | {f"curves_{robot}.png"}
            assert expected <= names, (robot, expected - names)
        report = (run_dir / "report.md").read_text()
        assert all(f"xbot_l -> {robot} (smoke)" in report for robot in cfg.targets)
        # progress off and one call of all iterations (checkpoint_every=0): the report says its
        # wall times are spread over the call, not measured per iteration
        assert "Progress was off: wall times are spread evenly" in report
        src = artifacts.load_checkpoint(run_dir / "source.npz")
        assert src["meta"]["robot"] == "xbot_l" and src["params"]["actor"]["layer_3"]["w"].shape[1] == 12

    def test_metrics_have_every_robot_preset_and_iteration(self, xbot_to_all):
        cfg, run_dir = xbot_to_all
        rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
        target = [r for r in rows if r["stage"] == "target"]
        seen = {(r["robot"], r["preset"], int(r["iteration"])) for r in target}
        n = cfg.target.ppo.num_iterations
        assert seen == {(r, p, i) for r in cfg.targets for p in PRESETS for i in range(1, n + 1)}
        assert all(np.isfinite(float(r["episode_reward"])) for r in rows)

    def test_hidden_layers_transfer_to_each_robot(self, xbot_to_all):
        cfg, run_dir = xbot_to_all
        for robot in cfg.targets:
            check_transfer(run_dir, f"target_{robot}_", robot)


# Slow (about 2 min of one core on the AMD EPYC of 2026-12-02): the one other source robot, a
# 10-joint one. xbot_to_all covers every robot's trainer and transfer in the default suite, and
# tests/test_config.py that this preset resolves at every scale.
@pytest.mark.slow
@pytest.mark.xdist_group("mit_to_xbot")
class TestMITToXBot:
    def test_runs_and_transfers(self, tmp_path_factory):
        cfg, run_dir = smoke("mit_to_xbot", tmp_path_factory)
        names = {p.name for p in run_dir.iterdir()}
        assert {"config.yaml", "metrics.csv", "curves.png", "report.md", "source.npz"} <= names
        assert {f"target_{p}_seed0.npz" for p in PRESETS} <= names
        check_transfer(run_dir, "target_", "xbot_l")
        # progress off and one call of all iterations (checkpoint_every=0): the report says its
        # wall times are spread over the call, not measured per iteration
        assert "Progress was off: wall times are spread evenly" in (run_dir / "report.md").read_text()
        src = artifacts.load_checkpoint(run_dir / "source.npz")
        assert src["meta"]["robot"] == "mit_humanoid"
        assert src["params"]["actor"]["layer_3"]["w"].shape[1] == 10  # MIT Humanoid: 10 joints

"""The command-grid evaluation (issue 20): the grid's axes, its bookkeeping on hand-made rollouts,
the verdict, the push schedule, the pushes in a rollout, and the CLI's refusals. The grid run
on a trained checkpoint is in tests/test_end_to_end.py (it shares the smoke run)."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ptrl_jax import command_grid, evaluate
from ptrl_jax.command_grid import CommandGrid


class TestAxes:
    def test_values_span_the_range_with_zero_and_the_check_commands(self):
        assert command_grid.axis_values(0.0, 1.0, 5) == (0.0, 0.25, 0.5, 0.75, 1.0)
        assert command_grid.axis_values(-0.3, 0.6, 4, include=[0.3]) == (-0.3, 0.0, 0.3, 0.6)
        # zero joins only where the range holds it; an included value outside the range does not
        assert command_grid.axis_values(0.2, 1.0, 3, include=[0.1]) == (0.2, 0.6, 1.0)
        assert command_grid.axis_values(0.0, 0.0, 3) == (0.0,)

    def test_default_grid_reads_the_training_ranges(self):
        cfg = envs.default_config("go2")
        c = dataclasses.replace(cfg.commands, lin_vel_x=(-1.0, 1.0), lin_vel_y=(-0.4, 0.4), yaw_rate=(-1.0, 1.0))
        grid = command_grid.default_grid(dataclasses.replace(cfg, commands=c), [(0.5, 0.0, 0.0)])
        assert grid.vx == (-1.0, -0.5, 0.0, 0.5, 1.0) and grid.vy == (-0.4, 0.0, 0.4) and grid.yaw == (-1.0, 0.0, 1.0)
        assert grid.commands().shape == (45, 3)
        assert (0.5, 0.0, 0.0) in {tuple(map(float, row)) for row in grid.commands()}

    def test_commands_enumerate_every_combination(self):
        grid = CommandGrid(vx=(0.0, 1.0), vy=(0.2,), yaw=(-0.5, 0.5))
        np.testing.assert_allclose(grid.commands(), [[0, 0.2, -0.5], [0, 0.2, 0.5], [1, 0.2, -0.5], [1, 0.2, 0.5]])

    @pytest.mark.parametrize("fields, words", [
        ({"vx": ()}, "grid vx"), ({"yaw": (0.0, float("nan"))}, "finite"), ({"seconds": 0.0}, "seconds"),
        ({"settle_s": 5.0, "seconds": 5.0}, "settle_s"), ({"push_seeds": 0}, "push_seeds"),
    ])
    def test_bad_grids_are_refused_naming_the_field(self, fields, words):
        with pytest.raises(ValueError, match=words):
            CommandGrid(**{"vx": (0.5,), "vy": (0.0,), "yaw": (0.0,), **fields})


def records(up_steps, velocities, fell, dt=0.5):
    """Hand-made records of cells x seeds x T steps: ``up_steps[c][s]`` steps up, each at
    ``velocities[c][s]``; ``fell[c][s]`` marks a fall on the step after them."""
    cells, seeds, steps = len(up_steps), len(up_steps[0]), 4
    alive = np.zeros((cells, seeds, steps), bool)
    falls = np.zeros((cells, seeds, steps), bool)
    vel = np.full((cells, seeds, steps, 3), 99.0)  # never counted: steps not up
    for c in range(cells):
        for s in range(seeds):
            n = up_steps[c][s]
            alive[c, s, :n] = True
            vel[c, s, :n] = velocities[c][s]
            if fell[c][s]:
                falls[c, s, n] = True
    return {"alive": alive, "fell": falls, "velocity": vel, "dt": dt}


class TestBookkeeping:
    def test_cell_errors_are_of_the_mean_velocity_over_steps_up(self):
        commands = np.array([[0.5, 0.0, 0.0], [1.0, 0.2, -0.5]])
        rec = records([[4], [2]], [[(0.4, 0.1, 0.0)], [(0.8, 0.2, -0.1)]], [[False], [True]])
        s = command_grid.summarize_grid(commands, rec)
        a, b = s["cells"]
        np.testing.assert_allclose(a["mean_velocity"], [0.4, 0.1, 0.0])
        np.testing.assert_allclose(a["error"], [0.1, 0.1, 0.0], atol=1e-12)
        assert not a["fell"] and a["time_up_s"] == 2.0
        np.testing.assert_allclose(b["error"], [0.2, 0.0, 0.4], atol=1e-12)  # the 99s after the fall are left out
        assert b["fell"] and b["fall_rate"] == 1.0 and b["time_up_s"] == 1.0
        np.testing.assert_allclose([s["mean_error"][k] for k in ("vx", "vy", "yaw")], [0.15, 0.05, 0.2])
        assert s["cells_with_fall"] == 1 and s["fall_rate"] == 0.5 and s["rollouts"] == 2

    def test_swing_within_a_rollout_is_rms_not_error(self):
        rec = records([[4]], [[(0.0, 0.0, 0.0)]], [[False]])
        rec["velocity"][0, 0, :, 0] = [0.3, 0.7, 0.3, 0.7]  # mean 0.5: on the command, swinging by 0.2
        s = command_grid.summarize_grid(np.array([[0.5, 0.0, 0.0]]), rec)
        assert s["cells"][0]["error"][0] == pytest.approx(0.0, abs=1e-12)
        assert s["cells"][0]["rms_error"][0] == pytest.approx(0.2)

    def test_settle_leaves_out_the_first_steps(self):
        rec = records([[4]], [[(0.5, 0.0, 0.0)]], [[False]], dt=0.5)
        rec["velocity"][0, 0, :2, 0] = 0.0  # 1 s of accelerating
        s = command_grid.summarize_grid(np.array([[0.5, 0.0, 0.0]]), rec, settle_s=1.0)
        assert s["cells"][0]["error"][0] == pytest.approx(0.0, abs=1e-12)
        assert command_grid.summarize_grid(np.array([[0.5, 0.0, 0.0]]), rec)["cells"][0]["error"][0] == pytest.approx(0.25)

    def test_fall_rate_counts_seeds(self):
        rec = records([[4, 1, 4, 2]], [[(0.5, 0, 0)] * 4], [[False, True, False, True]])
        s = command_grid.summarize_grid(np.array([[0.5, 0.0, 0.0]]), rec)
        assert s["cells"][0]["fall_rate"] == 0.5 and s["fall_rate"] == 0.5 and s["rollouts"] == 4
        # the cell's mean velocity pools every seed's steps up (4 + 1 + 4 + 2)
        assert s["cells"][0]["time_up_s"] == pytest.approx((4 + 1 + 4 + 2) / 4 * 0.5)

    def test_a_cell_with_no_step_up_is_nan_and_left_out_of_the_mean(self):
        rec = records([[4], [0]], [[(0.4, 0.0, 0.0)], [(0.0, 0.0, 0.0)]], [[False], [True]])
        s = command_grid.summarize_grid(np.array([[0.5, 0, 0], [1.0, 0, 0]]), rec)
        assert np.isnan(s["cells"][1]["error"][0])
        assert s["mean_error"]["vx"] == pytest.approx(0.1) and s["cells_with_fall"] == 1


    def test_standing_error_is_the_mean_command_and_tracked_the_share_removed(self):
        # yaw rates -0.3, 0, 0.3: standing still errs 0.2 on average; a robot turning at half the
        # command removes half of that; vy is never commanded, so its share is undefined
        commands = np.array([[0.5, 0.0, -0.3], [0.5, 0.0, 0.0], [1.0, 0.0, 0.3]])
        rec = records([[4], [4], [4]], [[(0.5, 0.0, -0.15)], [(0.5, 0.0, 0.0)], [(0.9, 0.0, 0.15)]],
                      [[False], [False], [False]])
        s = command_grid.summarize_grid(commands, rec)
        assert s["standing_error"]["yaw"] == pytest.approx(0.2) and s["mean_error"]["yaw"] == pytest.approx(0.1)
        assert s["tracked"]["yaw"] == pytest.approx(0.5)
        assert s["standing_error"]["vx"] == pytest.approx(2 / 3) and s["mean_error"]["vx"] == pytest.approx(0.1 / 3)
        assert s["tracked"]["vx"] == pytest.approx(0.95)
        assert s["standing_error"]["vy"] == 0.0 and np.isnan(s["tracked"]["vy"])

    def test_standing_error_leaves_out_the_cells_the_mean_leaves_out(self):
        rec = records([[4], [0]], [[(0.4, 0.0, 0.0)], [(0.0, 0.0, 0.0)]], [[False], [True]])
        s = command_grid.summarize_grid(np.array([[0.5, 0, 0], [1.0, 0, 0]]), rec)
        assert s["standing_error"]["vx"] == pytest.approx(0.5) and s["tracked"]["vx"] == pytest.approx(0.8)


class TestVerdict:
    grid = CommandGrid(vx=(0.5,), vy=(0.0,), yaw=(0.0,))

    def summary(self, vx=0.05, vy=0.05, yaw=0.1, falls=0, fall_rate=0.0):
        return {"cells": [{}] * 4, "mean_error": {"vx": vx, "vy": vy, "yaw": yaw}, "cells_with_fall": falls,
                "fall_rate": fall_rate, "rollouts": 4}

    def test_within_every_goal_passes(self):
        assert command_grid.verdict(self.grid, self.summary(), self.summary(fall_rate=0.05)) == {
            "passed": True, "why_not": "", "caveats": []}

    def test_a_goal_that_ignoring_the_axis_meets_is_a_caveat_not_a_failure(self):
        s = {**self.summary(yaw=0.201), "standing_error": {"vx": 0.5, "vy": 0.2, "yaw": 0.2},
             "tracked": {"vx": 0.9, "vy": 0.75, "yaw": -0.05}}
        v = command_grid.verdict(self.grid, s)
        assert v["why_not"] == "mean |yaw error| 0.201 > 0.2"
        assert len(v["caveats"]) == 1 and "yaw goal (0.2) is met by a robot that ignores yaw" in v["caveats"][0]
        assert "removes -5% of it" in v["caveats"][0]
        s["standing_error"]["yaw"] = 0.5
        assert command_grid.verdict(self.grid, s)["caveats"] == []

    def test_each_goal_missed_is_named(self):
        v = command_grid.verdict(self.grid, self.summary(vx=0.11, yaw=0.3, falls=1), self.summary(fall_rate=0.25))
        assert not v["passed"]
        for words in ("fell in 1 of 4 cells", "|vx error| 0.110 > 0.1", "|yaw error| 0.300 > 0.2", "25.0% of pushed"):
            assert words in v["why_not"]
        assert "vy" not in v["why_not"]

    def test_nan_error_fails(self):
        assert not command_grid.verdict(self.grid, self.summary(vy=float("nan")))["passed"]


class TestPushes:
    def test_schedule_kicks_at_every_interval_within_the_bound(self):
        kicks = np.asarray(command_grid.push_schedule(50, 0.02, 0.2, 0.5, jax.random.PRNGKey(0)))
        assert kicks.shape == (50, 2)
        pushed = np.flatnonzero(np.abs(kicks).sum(axis=1) > 0)
        np.testing.assert_array_equal(pushed, [10, 20, 30, 40])  # never at step 0
        assert np.all(np.abs(kicks) <= 0.5)
        other = np.asarray(command_grid.push_schedule(50, 0.02, 0.2, 0.5, jax.random.PRNGKey(1)))
        assert not np.allclose(kicks[pushed], other[pushed])

    def test_a_push_moves_the_base_from_its_step_on(self):
        """Go2 under zero action (MuJoCo C): identical to the unpushed rollout before the
        first push, off it from the push's step on."""
        env = command_grid.grid_env("go2", evaluate.fixed_command_config(envs.default_config("go2"), (0, 0, 0), 1.0), "mujoco")
        hold = lambda params, normalizer, obs, key: jnp.zeros(env.action_size)  # noqa: E731
        key = jax.random.PRNGKey(0)
        still, pushed = (jax.jit(command_grid.make_rollout(env, hold, 0.2, p, 0.1, 0.5))(None, None, jnp.zeros(3), key)
                         for p in (False, True))
        every = 5  # 0.1 s at Go2's 20 ms control step
        np.testing.assert_array_equal(still["velocity"][:every], pushed["velocity"][:every])
        moved = np.abs(np.asarray(pushed["velocity"]) - np.asarray(still["velocity"]))[:, :2].max(axis=1)
        assert moved[every] > 0.05 and moved[every:].min() > 0.01


class TestGridCli:
    def test_grid_arguments_need_grid(self, capsys):
        assert evaluate.main(["ckpt=x.npz", "pushes=true"]) == 2
        assert "only with grid=true" in capsys.readouterr().err

    def test_single_rollout_arguments_are_refused_with_grid(self, capsys):
        assert evaluate.main(["ckpt=x.npz", "grid=true", "vx=0.5", "check=true"]) == 2
        err = capsys.readouterr().err
        assert "grid=true" in err and "check, vx" in err

    def test_a_bad_axis_is_refused_naming_it(self, monkeypatch, capsys, tmp_path):
        policy = {"robot": "go2", "env": envs.default_config("go2")}
        monkeypatch.setattr(evaluate, "policy_from_checkpoint", lambda path: policy)
        assert evaluate.main([f"ckpt={tmp_path}/x.npz", "grid=true", "grid_vy=[a,b"]) == 2
        assert "grid_vy=" in capsys.readouterr().err
        assert evaluate.main([f"ckpt={tmp_path}/x.npz", "grid=true", "grid_yaw=[]"]) == 2
        assert "grid_yaw" in capsys.readouterr().err

    def test_an_existing_grid_is_not_overwritten(self, monkeypatch, capsys, tmp_path):
        monkeypatch.setattr(evaluate, "policy_from_checkpoint", lambda path: {"robot": "go2", "env": envs.default_config("go2")})
        (tmp_path / "g").mkdir()
        (tmp_path / "g" / "grid.json").write_text(json.dumps({"kept": True}))
        assert evaluate.main([f"ckpt={tmp_path}/x.npz", "grid=true", f"out={tmp_path}/g"]) == 2
        assert "already holds a grid" in capsys.readouterr().err
        assert json.loads((tmp_path / "g" / "grid.json").read_text()) == {"kept": True}


class TestOutputs:
    def _write(self, tmp_path, **model):
        grid = CommandGrid(vx=(0.0, 0.5), vy=(0.0,), yaw=(0.0,))
        summary = command_grid.summarize_grid(grid.commands(), records([[4], [4]], [[(0.0, 0.0, 0.0)], [(0.4, 0.0, 0.0)]],
                                                                        [[False], [False]]))
        judged = command_grid.verdict(grid, summary, None)
        command_grid.write_outputs(tmp_path, "xbot_l", "mujoco", grid, summary, None, judged, **model)
        return json.loads((tmp_path / "grid.json").read_text()), (tmp_path / "grid.md").read_text()

    def test_grid_json_names_the_model_version_it_graded(self, tmp_path):
        """grid.json records the robot's MJCF digest, so a grid can be told from one graded on
        another version of the model (XBot-L's soles changed in stop 57)."""
        now = envs.asset_sha256("xbot_l.xml")
        saved, text = self._write(tmp_path, trained_on=now)
        assert saved["model"] == {"asset": "xbot_l.xml", "graded_on": now, "trained_on": now}
        assert "another version" not in text
        np.testing.assert_allclose(saved["summary"]["mean_error"]["vx"], 0.05)

    def test_a_policy_trained_on_another_model_version_is_named_in_grid_md(self, tmp_path):
        saved, text = self._write(tmp_path, asset="xbot_l.xml", trained_on="0123456789abcdef")
        assert saved["model"]["trained_on"] == "0123456789abcdef"
        assert "trained on another version of xbot_l.xml (sha256 0123456789abcdef)" in text

"""Fig. 6 (commanded vs actual velocity) and filmstrips (Figs. 4, 8, 9) from rollout records."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ptrl_jax.evaluate import parse_schedule, rollout_mjx
from ptrl_jax.io.figures import (FIG6_SCHEDULE, frame_steps, plot_velocity_tracking, render_frames, save_filmstrip,
                              schedule_commands)
from ptrl_jax.io import summary
from ptrl_jax.io.overrides import ConfigError

PNG = b"\x89PNG\r\n\x1a\n"


def records(steps=40, fall_at=None):
    model = envs.LocomotionGymEnv("go2").model
    qpos = np.tile(np.asarray(model.qpos0), (steps, 1))
    qpos[:, 7:] += np.linspace(0, 0.6, steps)[:, None]  # joints sweep: the frames must differ
    alive = np.ones(steps, bool)
    fell = np.zeros(steps, bool)
    if fall_at is not None:
        fell[fall_at] = True
        alive[fall_at + 1:] = False
    cmd = schedule_commands(FIG6_SCHEDULE, steps)
    return {"alive": alive, "fell": fell, "velocity": cmd + 0.05, "command": cmd, "qpos": qpos,
            "dt": 0.02, "model": model}


class TestSchedule:
    def test_rows_hold_for_equal_shares(self):
        rows = [[0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0.5]]
        # step i takes row (3 i) // 7: 0 0 0 1 1 2 2
        np.testing.assert_allclose(schedule_commands(rows, 7)[:, 0], [0.1, 0.1, 0.1, 0.2, 0.2, 0.3, 0.3])
        assert schedule_commands(rows, 7)[-1, 2] == pytest.approx(0.5)

    @pytest.mark.parametrize("text", ["[[0.3,0]]", "fast", "[]"])
    def test_bad_schedules_are_refused(self, text):
        with pytest.raises(ConfigError, match="schedule="):
            parse_schedule(text)

    def test_the_rollout_follows_the_schedule(self):
        # The jitted rollout of evaluate (MuJoCo C's engine: its compile is a third of MJX's; the
        # schedule is the env's command code, the same for both engines).
        rows = ((0.2, 0.0, 0.0), (0.6, 0.1, -0.3))
        actor = lambda obs, key: jnp.zeros(12)  # noqa: E731
        config = dataclasses.replace(envs.default_config("go2"), engine="mujoco")
        rec = rollout_mjx("go2", config, actor, (0.0, 0.0, 0.0), 0.2, schedule=rows)
        np.testing.assert_allclose(rec["command"], schedule_commands(rows, 10), atol=1e-7)


class TestFigures:
    def test_velocity_tracking_png(self, tmp_path):
        plot_velocity_tracking(tmp_path / "v.png", records(fall_at=30), "go2")
        assert (tmp_path / "v.png").read_bytes()[:8] == PNG

    def test_frames_show_the_motion_up_to_a_fall(self):
        rec = records(fall_at=19)
        frames = render_frames(rec, frames=3, width=96, height=72)
        assert [f.shape for f in frames] == [(72, 96, 3)] * 3
        assert not np.array_equal(frames[0], frames[-1])  # the legs moved
        # The last frame is the last step before the fall (18), not the end of the rollout.
        later = render_frames({**rec, "alive": np.ones(40, bool)}, frames=3, width=96, height=72)
        assert not np.array_equal(frames[-1], later[-1])

    def test_a_span_draws_the_last_seconds_before_the_end(self):
        # Falls at step 29, whose record is already the auto-reset state: frames end at step 28.
        rec = records(steps=40, fall_at=29)  # dt 0.02
        np.testing.assert_array_equal(frame_steps(rec, 3), [0, 14, 28])
        np.testing.assert_array_equal(frame_steps(rec, 3, span_s=0.2), [18, 23, 28])  # 10 steps back
        np.testing.assert_array_equal(frame_steps(rec, 2, span_s=5.0), [0, 28])  # clipped at the start
        no_fall = records(steps=40)
        np.testing.assert_array_equal(frame_steps(no_fall, 2), [0, 39])

    def test_filmstrip_png(self, tmp_path):
        save_filmstrip(tmp_path / "f.png", records(), "go2", frames=4)
        assert (tmp_path / "f.png").read_bytes()[:8] == PNG


class TestTrainingCurves:
    """``summary.plot_curves``: the run's curves.png, with and without a source curve."""

    CURVES = {p: {"env_steps": np.array([100.0, 200.0, 300.0]), "reward": np.array([[1.0, 2.0, 3.0], [1.5, 2.5, 3.5]])}
              for p in ("none", "scratch")}

    def test_source_panel_beside_the_targets(self, tmp_path):
        axes = summary.plot_curves(tmp_path / "c.png", self.CURVES, "t", [(0, 0.0), (10, 1.0)])
        assert len(axes) == 2 and axes[0].get_title() == "source (SLRT)"
        assert len(axes[1].get_lines()) == 2  # one mean line per preset
        assert (tmp_path / "c.png").read_bytes()[:8] == PNG

    def test_no_empty_source_panel_without_a_source(self, tmp_path):
        # a loaded source (source_checkpoint) or scratch-only runs have no source curve
        axes = summary.plot_curves(tmp_path / "c.png", self.CURVES, "t")
        assert len(axes) == 1 and axes[0].get_xlabel() == "target env steps (millions)"
        assert (tmp_path / "c.png").read_bytes()[:8] == PNG

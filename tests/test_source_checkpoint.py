"""Starting from a trained source (``source_checkpoint``): checked before anything compiles."""

import warnings
from typing import NamedTuple

import jax
import numpy as np
import pytest

from ptrl_jax.io import artifacts
from ptrl_jax.io.artifacts import CheckpointError
from ptrl_jax.io.overrides import load_experiment
from ptrl_jax.core.program import ProgramOutput, make_program
from ptrl_jax.io.checkpoints import load_source_params, save_checkpoints
from ptrl_jax.io.progress import Progress


@pytest.fixture(scope="module")
def go2_program():
    cfg = load_experiment("go2_to_xbot", ["scale=smoke"])
    return cfg, make_program(cfg)


def write_source(path, params, robot="go2", normalizer=None, stage="source", **meta):
    if normalizer is None:
        normalizer = {k: {"mean": np.zeros(n, np.float32), "m2": np.ones(n, np.float32), "count": np.float32(1)}
                      for k, n in (("state", 45), ("privileged_state", 53))}
    artifacts.save_checkpoint(path, params, normalizer, jax.tree.map(lambda p: np.zeros(p.shape, bool), params),
                              {"robot": robot, "stage": stage, **meta})


# One xdist worker takes the whole class, so the smoke program (the module's fixture, about 15 s to
# build) is built once rather than once per worker.
@pytest.mark.xdist_group("source_checkpoint")
class TestLoadSourceParams:
    def test_loads_the_checkpoint_params(self, go2_program, tmp_path):
        cfg, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(3)))
        write_source(tmp_path / "source.npz", params)
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'source.npz'}"])
        loaded = load_source_params(cfg, program)
        assert jax.tree.all(jax.tree.map(np.array_equal, loaded["params"], params))
        assert loaded["normalizer"]["state"].m2.shape == (45,) and float(loaded["normalizer"]["state"].count) == 1.0
        assert cfg.source_iterations == 0 and cfg.source.ppo.num_iterations == 2

    def test_a_from_scratch_runs_target_checkpoint_serves_as_a_source(self, go2_program, tmp_path):
        # A source trained alone (exp=go2_from_scratch, say) is a target checkpoint of that robot:
        # the robot and the network decide, not the stage it was written by (docs/table4.md, stop 50).
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(4)))
        write_source(tmp_path / "target_scratch_seed0.npz", params, stage="target")
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'target_scratch_seed0.npz'}"])
        loaded = load_source_params(cfg, program)
        assert jax.tree.all(jax.tree.map(np.array_equal, loaded["params"], params))

    def test_a_source_trained_on_another_model_version_warns(self, go2_program, tmp_path):
        """The run goes on (same shapes), but says the source's physics were another MJCF's."""
        import envs

        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(5)))
        write_source(tmp_path / "old.npz", params, asset_sha256="0123456789abcdef")
        write_source(tmp_path / "same.npz", params, asset_sha256=envs.asset_sha256("go2.xml"))
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'old.npz'}"])
        with pytest.warns(UserWarning, match=r"old.npz was trained on another version of go2.xml \(sha256 0123456789abcdef"):
            load_source_params(cfg, program)
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'same.npz'}"])
        with warnings.catch_warnings():
            warnings.simplefilter("error", UserWarning)
            load_source_params(cfg, program)

    def test_another_robot_is_refused(self, go2_program, tmp_path):
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(0)))
        write_source(tmp_path / "a1.npz", params, robot="a1")
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'a1.npz'}"])
        with pytest.raises(CheckpointError, match="'a1' policy; this experiment needs a 'go2' one"):
            load_source_params(cfg, program)

    def test_another_network_is_refused_naming_the_leaf(self, go2_program, tmp_path):
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(0)))
        params["actor"]["layer_1"]["w"] = params["actor"]["layer_1"]["w"][:, :64]
        write_source(tmp_path / "small.npz", params)
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'small.npz'}"])
        with pytest.raises(CheckpointError, match=r"\['actor'\]\['layer_1'\]\['w'\] is \[512, 64\]"):
            load_source_params(cfg, program)

    def test_a_checkpoint_without_normaliser_statistics_is_refused(self, go2_program, tmp_path):
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(0)))
        write_source(tmp_path / "nonorm.npz", params, normalizer={})
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'nonorm.npz'}"])
        with pytest.raises(CheckpointError, match="no normaliser statistics for '(state|privileged_state)'"):
            load_source_params(cfg, program)

    def test_a_missing_file_is_refused(self, go2_program, tmp_path):
        _, program = go2_program
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'nope.npz'}"])
        with pytest.raises(CheckpointError, match="does not exist"):
            load_source_params(cfg, program)


class TestProgressWithoutSourceStage:
    def test_the_target_stage_starts_at_zero(self):
        # Regression: with no source iterations, the first target stamp found no source time.
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", "source_checkpoint=x.npz"])
        progress = Progress(cfg, show=True)
        progress.start()
        progress.hook("target")({"run_id": 0, "iteration": 0, "episode_reward": 1.0})
        progress.close()
        assert progress.stage_start["target"] == 0.0 and (("target", 0, 0) in progress.times)


class TestProgressSpreadStamps:
    """``Progress.spread_over``: how many iterations a call ran whose wall times were spread
    evenly rather than stamped by the callback (the report says so when it is over one)."""

    def test_a_call_of_three_iterations_without_callbacks_is_spread(self):
        cfg = load_experiment("go2_to_xbot", ["scale=smoke"])
        progress = Progress(cfg, show=False)
        progress.start()
        progress.record_slice((0, 0), (2, 1), 0.0)  # two source iterations and one target
        assert progress.spread_over == 3
        assert progress.times[("source", 0, 1)] < progress.times[("source", 0, 2)] <= progress.times[("target", 0, 1)]

    def test_stamps_from_the_callback_are_not_spread(self):
        cfg = load_experiment("go2_to_xbot", ["scale=smoke"])
        progress = Progress(cfg, show=True)
        progress.start()
        for it in (1, 2):
            progress.hook("source")({"run_id": 0, "iteration": it, "episode_reward": 1.0})
        progress.record_slice((0, 0), (2, 0), 0.0)
        progress.close()
        assert progress.spread_over == 0


class _Stage(NamedTuple):  # the fields of a TrainState that checkpoints hold
    params: dict
    normalizer: dict
    frozen: dict


def fake_output(cfg):
    """A ProgramOutput of tiny arrays (source weights -1, targets +1), with the [variants, seeds]
    axes of the target states."""
    lead = (len(cfg.variants), cfg.seeds)
    target = _Stage({"w": np.ones((*lead, 2))}, {}, {"w": np.zeros((*lead, 2), bool)})
    source = _Stage({"w": -np.ones(2)}, {}, {"w": np.zeros(2, bool)})
    return ProgramOutput(source, {}, {r: target for r in cfg.targets}, {})


class TestCheckpointsOfARun:
    """Which checkpoints a run writes, by how it got (or did not get) its source."""

    def names(self, tmp_path, overrides):
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", "seeds=2", "freeze_ratio=[]", *overrides])
        run_dir = tmp_path / "run"
        run_dir.mkdir()
        save_checkpoints(cfg, run_dir, fake_output(cfg))
        return cfg, run_dir, {p.name for p in run_dir.iterdir()}

    def test_from_a_source_checkpoint_it_copies_the_source_and_saves_every_target(self, tmp_path):
        # Regression: a source_checkpoint run used to write source.npz and no target checkpoints.
        source = tmp_path / "trained.npz"
        write_source(source, {"w": np.arange(2.0)})
        cfg, run_dir, names = self.names(tmp_path, ["freeze_presets=[L2,scratch]", f"source_checkpoint={source}"])
        assert names == {"source.npz"} | {f"target_{p}_seed{s}.npz" for p in ("L2", "scratch") for s in (0, 1)}
        assert (run_dir / "source.npz").read_bytes() == source.read_bytes()

    def test_scratch_only_trains_and_saves_no_source(self, tmp_path):
        cfg, run_dir, names = self.names(tmp_path, ["freeze_presets=[scratch]"])
        assert not cfg.trains_source and cfg.source_iterations == 0
        assert names == {"target_scratch_seed0.npz", "target_scratch_seed1.npz"}
        ckpt = artifacts.load_checkpoint(run_dir / "target_scratch_seed1.npz")
        assert ckpt["meta"]["robot"] == "xbot_l" and ckpt["meta"]["seed"] == 1

    def test_a_transfer_run_saves_its_trained_source(self, tmp_path):
        cfg, run_dir, names = self.names(tmp_path, ["freeze_presets=[L1,scratch]"])
        assert cfg.trains_source and cfg.source_iterations == 2
        assert "source.npz" in names and len(names) == 5
        assert np.array_equal(artifacts.load_checkpoint(run_dir / "source.npz")["params"]["w"], [-1.0, -1.0])

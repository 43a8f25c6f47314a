"""Starting from a trained source (``source_checkpoint``): checked before anything compiles."""

import jax
import numpy as np
import pytest

from ptrl_jax import artifacts
from ptrl_jax.artifacts import CheckpointError
from ptrl_jax.overrides import load_experiment
from ptrl_jax.program import make_program
from ptrl_jax.run import Progress, load_source_params


@pytest.fixture(scope="module")
def go2_program():
    cfg = load_experiment("go2_to_xbot", ["scale=smoke"])
    return cfg, make_program(cfg)


def write_source(path, params, robot="go2"):
    artifacts.save_checkpoint(path, params, {}, jax.tree.map(lambda p: np.zeros(p.shape, bool), params),
                              {"robot": robot, "stage": "source"})


class TestLoadSourceParams:
    def test_loads_the_checkpoint_params(self, go2_program, tmp_path):
        cfg, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(3)))
        write_source(tmp_path / "source.npz", params)
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'source.npz'}"])
        loaded = load_source_params(cfg, program)
        assert jax.tree.all(jax.tree.map(np.array_equal, loaded, params))
        assert cfg.source_iterations == 0 and cfg.source.ppo.num_iterations == 2

    def test_another_robot_is_refused(self, go2_program, tmp_path):
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(0)))
        write_source(tmp_path / "a1.npz", params, robot="a1")
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'a1.npz'}"])
        with pytest.raises(CheckpointError, match="'a1' policy; this experiment's source.robot is 'go2'"):
            load_source_params(cfg, program)

    def test_another_network_is_refused_naming_the_leaf(self, go2_program, tmp_path):
        _, program = go2_program
        params = jax.tree.map(np.asarray, program.source_trainer.init_params(jax.random.PRNGKey(0)))
        params["actor"]["layer_1"]["w"] = params["actor"]["layer_1"]["w"][:, :64]
        write_source(tmp_path / "small.npz", params)
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"source_checkpoint={tmp_path / 'small.npz'}"])
        with pytest.raises(CheckpointError, match=r"\['actor'\]\['layer_1'\]\['w'\] is \[512, 64\]"):
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

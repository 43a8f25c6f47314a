"""ONNX and npz export: the exported actor reproduces the JAX forward (normalisation included)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ptrl_jax import export
from ptrl_jax.core import normalization
from ptrl_jax.io.artifacts import save_checkpoint
from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.freeze import empty_mask
from ptrl_jax.core.networks import init_actor_critic, policy_apply
from ptrl_jax.core.train import normalize_obs

OBS, PRIV, ACT = 45, 53, 12
NET = NetworkConfig(actor_hidden=(32, 16, 8), critic_hidden=(8,))


def make_policy():
    params = init_actor_critic(jax.random.PRNGKey(0), NET, OBS, PRIV, ACT)
    # Non-trivial statistics: shifted, scaled observations (so mean and std both matter).
    data = jax.random.normal(jax.random.PRNGKey(1), (500, OBS)) * jnp.linspace(0.1, 5.0, OBS) + 3.0
    stats = {"state": normalization.update(normalization.init(OBS), data),
             "privileged_state": normalization.init(PRIV)}
    return {"robot": "go2", "env": envs.default_config("go2"), "network": NET, "params": params,
            "normalizer": stats, "normalize_observations": True}


def jax_actions(policy, obs):
    normed = normalize_obs(policy["normalizer"], {"state": jnp.asarray(obs)}, True)
    return np.asarray(policy_apply(policy["params"], normed, NET).mean)


def sample_obs():
    # Includes far-out values, so the normaliser's clip is exercised too.
    obs = np.random.default_rng(0).normal(3.0, 4.0, (64, OBS)).astype(np.float32)
    obs[0] = 1e3
    return obs


class TestNumpyExport:
    def test_npz_forward_matches_jax(self, tmp_path):
        policy = make_policy()
        path = export.export_npz(policy, tmp_path / "p.policy.npz")
        arrays, meta = export.load_npz(path)
        obs = sample_obs()
        np.testing.assert_allclose(export.numpy_forward(arrays, obs), jax_actions(policy, obs), atol=1e-5)
        assert meta["robot"] == "go2" and meta["observation_size"] == OBS and meta["action_size"] == ACT
        assert meta["action_scale"] == pytest.approx(0.25)


class TestOnnxExport:
    def test_onnxruntime_matches_jax(self, tmp_path):
        ort = pytest.importorskip("onnxruntime")
        policy = make_policy()
        path = export.export_onnx(policy, tmp_path / "p.onnx")
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        obs = sample_obs()
        (onnx_actions,) = session.run(["action"], {"obs": obs})
        diff = np.max(np.abs(onnx_actions - jax_actions(policy, obs)))
        assert diff < 1e-5, diff

    def test_cli_writes_onnx_from_checkpoint(self, tmp_path, capsys):
        pytest.importorskip("onnx")
        policy = make_policy()
        ckpt = tmp_path / "source.npz"
        meta = {"robot": "go2", "network": {"actor_hidden": [32, 16, 8], "critic_hidden": [8]}, "env": {},
                "normalize_observations": True}
        save_checkpoint(ckpt, policy["params"], policy["normalizer"], empty_mask(policy["params"]), meta)
        assert export.main([f"ckpt={ckpt}", "format=onnx"]) == 0
        assert (tmp_path / "source.onnx").is_file()

    def test_cli_refuses_unknown_format_and_writes_nothing(self, tmp_path, capsys):
        assert export.main([f"ckpt={tmp_path / 'x.npz'}", "format=tflite"]) == 2
        assert "format='tflite'" in capsys.readouterr().err
        assert list(tmp_path.iterdir()) == []

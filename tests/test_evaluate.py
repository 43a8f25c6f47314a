"""Evaluation actors: the mean action, or actions sampled as in training (``stochastic=true``)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from ptrl_jax import evaluate
from ptrl_jax.core import normalization
from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.networks import init_actor_critic, policy_apply
from ptrl_jax.io.checkpoints import warn_if_model_changed

OBS, PRIV, ACT = 45, 53, 12
NET = NetworkConfig(actor_hidden=(32, 16, 8), critic_hidden=(8,), init_noise_std=0.3)


def policy_parts():
    params = init_actor_critic(jax.random.PRNGKey(0), NET, OBS, PRIV, ACT)
    stats = {"state": normalization.init(OBS), "privileged_state": normalization.init(PRIV)}
    return params, stats


def one_obs():
    return {"state": jax.random.normal(jax.random.PRNGKey(1), (OBS,)), "privileged_state": jnp.zeros(PRIV)}


class TestActor:
    def test_the_mean_actor_ignores_the_key(self):
        params, stats = policy_parts()
        act = evaluate.make_actor(params, stats, NET)
        obs = one_obs()
        a, b = act(obs, jax.random.PRNGKey(0)), act(obs, jax.random.PRNGKey(1))
        np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(a, policy_apply(params, obs, NET).mean, rtol=1e-6)

    def test_the_stochastic_actor_samples_the_policy_gaussian(self):
        params, stats = policy_parts()
        act = evaluate.make_actor(params, stats, NET, stochastic=True)
        obs = one_obs()
        n = 20_000
        samples = np.asarray(jax.vmap(lambda k: act(obs, k))(jax.random.split(jax.random.PRNGKey(2), n)))
        mean = np.asarray(policy_apply(params, obs, NET).mean)
        # std 0.3 per action: the sample mean lies within 5 standard errors (0.3 / sqrt(n) each),
        # and the sample std within 3 % of 0.3.
        np.testing.assert_allclose(samples.mean(axis=0), mean, atol=5 * 0.3 / np.sqrt(n))
        np.testing.assert_allclose(samples.std(axis=0), 0.3, rtol=0.03)


class TestStochasticRollout:
    """Five control steps of Go2 in the MuJoCo C env (no MJX compile)."""

    def rollout(self, stochastic, seed):
        params, stats = policy_parts()
        actor = evaluate.make_actor(params, stats, NET, stochastic=stochastic)
        rec = evaluate.rollout_mujoco("go2", envs.default_config("go2"), actor, (0.5, 0.0, 0.0), 0.1, seed)
        return rec["qpos"]

    def test_the_seed_picks_the_samples(self):
        a, b, c = self.rollout(True, 0), self.rollout(True, 0), self.rollout(True, 1)
        np.testing.assert_array_equal(a, b)
        assert np.abs(a - c).max() > 1e-4

    def test_mean_actions_do_not_depend_on_the_seed(self):
        np.testing.assert_array_equal(self.rollout(False, 0), self.rollout(False, 1))

    def test_sampled_actions_move_the_robot_differently_from_the_mean(self):
        assert np.abs(self.rollout(True, 0) - self.rollout(False, 0)).max() > 1e-4


class TestCli:
    def test_a_bad_stochastic_value_is_refused_naming_the_key(self, capsys):
        assert evaluate.main(["ckpt=missing.npz", "stochastic=maybe"]) == 2
        assert "stochastic" in capsys.readouterr().err


def summary(fell=False, survived=20.0, vx=0.45, command_vx=0.5):
    """``evaluate.summarize``'s fields for a hand-made rollout."""
    return {"fell": fell, "time_survived_s": survived, "mean_velocity": [vx, 0.0, 0.0],
            "forward_speed_error": abs(vx - command_vx)}


class TestWalkingCheckVerdict:
    WALK = evaluate.WalkingCheck("walk", (0.5, 0.0, 0.0))

    def test_no_fall_within_the_tolerance_passes(self):
        v = evaluate.check_verdict(self.WALK, summary(vx=0.36))  # 0.14 from 0.5
        assert v["passed"] and v["why_not"] == ""

    def test_standing_still_under_a_walk_command_fails_naming_the_speed(self):
        v = evaluate.check_verdict(self.WALK, summary(vx=0.004))
        assert not v["passed"] and "forward speed 0.004" in v["why_not"]

    def test_a_fall_fails_even_at_the_right_speed(self):
        v = evaluate.check_verdict(self.WALK, summary(fell=True, survived=1.72, vx=0.5))
        assert not v["passed"] and v["why_not"] == "fell at 1.72 s"

    def test_no_surviving_step_fails(self):
        v = evaluate.check_verdict(self.WALK, summary(fell=True, survived=0.0, vx=float("nan")))
        assert not v["passed"] and "forward speed nan" in v["why_not"]


class TestWalkingChecksPerFamily:
    def test_quadrupeds_walk_at_half_a_metre_per_second(self):
        for robot in ("go2", "a1", "anymal_b", "anymal_c"):
            assert [c.command for c in evaluate.walking_checks(robot)] == [(0.5, 0.0, 0.0)]

    def test_bipeds_stand_then_walk_at_0_3(self):
        for robot in ("xbot_l", "mit_humanoid", "cassie", "tron1"):
            checks = evaluate.walking_checks(robot)
            assert [(c.name, c.command) for c in checks] == [("stand", (0.0, 0.0, 0.0)), ("walk", (0.3, 0.0, 0.0))]
            assert all(c.seconds == 20.0 and c.max_speed_error == 0.15 for c in checks)

    def test_each_check_is_a_deterministic_rollout_of_its_command(self, monkeypatch):
        calls = []

        def fake_evaluate(**kw):
            calls.append(kw)
            return summary(vx=kw["command"][0], command_vx=kw["command"][0])

        policy = {"robot": "cassie", "env": "ENV", "params": "P", "normalizer": "N", "network": "NET",
                  "normalize_observations": True}
        monkeypatch.setattr(evaluate, "evaluate_policy", fake_evaluate)
        verdicts = evaluate.run_walking_check(policy, seed=3)
        assert [c["command"] for c in calls] == [(0.0, 0.0, 0.0), (0.3, 0.0, 0.0)]
        assert all(c["seconds"] == 20.0 and c["seed"] == 3 and "stochastic" not in c for c in calls)
        assert [v["passed"] for v in verdicts] == [True, True]


class TestCheckCli:
    def policy(self, robot):
        return {"robot": robot, "env": None, "params": None, "normalizer": None, "network": None,
                "normalize_observations": True}

    def test_exit_status_says_whether_every_check_passed(self, monkeypatch, capsys):
        monkeypatch.setattr(evaluate, "policy_from_checkpoint", lambda path: self.policy("tron1"))
        walks_in_place = lambda **kw: summary(vx=0.0, command_vx=kw["command"][0])  # noqa: E731
        monkeypatch.setattr(evaluate, "evaluate_policy", walks_in_place)
        assert evaluate.main(["ckpt=x.npz", "check=true"]) == 1  # stands, so the walk fails
        out = capsys.readouterr().out
        assert "stand vx 0.00" in out and ": pass" in out and "FAIL (forward speed 0.000" in out
        assert out.rstrip().endswith("fails")
        monkeypatch.setattr(evaluate, "evaluate_policy", lambda **kw: summary(vx=0.5))
        monkeypatch.setattr(evaluate, "policy_from_checkpoint", lambda path: self.policy("go2"))
        assert evaluate.main(["ckpt=x.npz", "check=true"]) == 0
        assert capsys.readouterr().out.rstrip().endswith("passes")

    def test_rollout_arguments_are_refused_with_check(self, capsys):
        assert evaluate.main(["ckpt=x.npz", "check=true", "vx=1.0", "seconds=5"]) == 2
        err = capsys.readouterr().err
        assert "check=true" in err and "seconds, vx" in err

    def test_a_bad_check_value_is_refused_naming_the_key(self, capsys):
        assert evaluate.main(["ckpt=x.npz", "check=perhaps"]) == 2
        assert "check" in capsys.readouterr().err


class TestModelVersion:
    """Checkpoints carry their robot model's ``asset_sha256``; ``evaluate`` warns when the installed
    MJCF is another version (the policy still plays, on the installed model)."""

    def test_the_digest_follows_the_file(self, tmp_path, monkeypatch):
        import envs.base

        (tmp_path / "go2.xml").write_bytes((envs.base.ASSETS_DIR / "go2.xml").read_bytes())
        monkeypatch.setattr(envs.base, "ASSETS_DIR", tmp_path)
        same = envs.asset_sha256("go2.xml")
        (tmp_path / "go2.xml").write_bytes((tmp_path / "go2.xml").read_bytes() + b"\n")
        assert len(same) == 16 and envs.asset_sha256("go2.xml") != same

    def test_once_loaded_the_digest_is_the_loaded_files(self, tmp_path, monkeypatch):
        """A model edited while a run trains does not stamp the run's checkpoints with the edit."""
        import envs.base

        (tmp_path / "go2.xml").write_bytes((envs.base.ASSETS_DIR / "go2.xml").read_bytes())
        monkeypatch.setattr(envs.base, "ASSETS_DIR", tmp_path)
        monkeypatch.setattr(envs.base, "_LOADED_DIGESTS", {})
        envs.base.load_mj_model(envs.default_config("go2"))
        loaded = envs.asset_sha256("go2.xml")
        (tmp_path / "go2.xml").write_bytes((tmp_path / "go2.xml").read_bytes() + b"\n")
        assert envs.asset_sha256("go2.xml") == loaded
        envs.base.load_mj_model(envs.default_config("go2"))  # loaded again: the new version
        assert envs.asset_sha256("go2.xml") != loaded

    def test_a_missing_asset_is_named(self):
        with pytest.raises(FileNotFoundError, match="no_such_robot.xml"):
            envs.asset_sha256("no_such_robot.xml")

    def test_another_model_version_warns_naming_both_digests(self):
        now = envs.asset_sha256("xbot_l.xml")
        with pytest.warns(UserWarning, match=rf"another version of xbot_l.xml \(sha256 0123456789abcdef, installed {now}\)"):
            warn_if_model_changed("old.npz", {"asset_sha256": "0123456789abcdef"}, "xbot_l.xml")

    @pytest.mark.parametrize("meta", [{}, "current"])
    def test_the_same_model_or_an_unrecorded_one_is_silent(self, meta, recwarn):
        meta = {"asset_sha256": envs.asset_sha256("xbot_l.xml")} if meta == "current" else meta
        warn_if_model_changed("ckpt.npz", meta, "xbot_l.xml")
        assert not [w for w in recwarn if "another version" in str(w.message)]

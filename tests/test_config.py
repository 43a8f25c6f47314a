"""Config resolution and refusal: bad input is refused before compiling, naming the key."""


import pytest

from ptrl_jax import run as run_cli
from ptrl_jax.overrides import ConfigError, load_experiment


class TestOverrides:
    def test_scale_and_dotted_overrides(self):
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", "target.ppo.learning_rate=3e-4", "seeds=3",
                                              "freeze_presets=[L2,scratch]", "source.env.commands.lin_vel_x=[0,1]"])
        assert cfg.scale == "smoke" and cfg.seeds == 3
        assert cfg.target.ppo.learning_rate == 3e-4
        assert cfg.freeze_presets == ("L2", "scratch")
        assert cfg.source.env.commands.lin_vel_x == (0.0, 1.0)
        assert cfg.source.ppo.num_envs == 32  # from the smoke section

    @pytest.mark.parametrize("arg,message", [
        ("ppo.learning_rate=1e-3", "did you mean '(source|target).ppo.learning_rate'"),
        ("target.ppo.learnin_rate=1e-3", "did you mean 'target.ppo.learning_rate'"),
        ("seeds=two", "seeds: expected an integer"),
        ("target.ppo.gamma=1.5", "gamma must be in"),
        ("target.ppo.num_minibatches=7", "not divisible"),
        ("freeze_presets=[L3]", "unknown \\['L3'\\]"),
        ("scale=huge", "scale must be one of"),
        ("target.robot=xbot", "did you mean 'xbot_l'"),
        ("source.env.kp=[1,2,3]", None),  # caught when the env is built (3 values for 12 joints)
    ])
    def test_bad_input_is_refused_with_the_key_named(self, arg, message):
        if message is None:
            import envs

            cfg = load_experiment("go2_to_xbot", [arg])
            with pytest.raises(ValueError, match="kp has 3 values"):
                envs.make(cfg.source.robot, cfg.source.env)
            return
        with pytest.raises(ConfigError, match=message):
            load_experiment("go2_to_xbot", [arg])

    def test_unknown_experiment(self):
        with pytest.raises(ConfigError, match="did you mean 'go2_to_xbot'"):
            load_experiment("go2_to_xbt")


class TestRefusedRunWritesNothing:
    def test_cli_exit_code_and_no_files(self, tmp_path, capsys):
        runs = tmp_path / "runs"
        code = run_cli.main(["exp=go2_to_xbot", f"runs_dir={runs}", "target.ppo.clip_epsilon=-1"])
        assert code == 2
        assert "clip_epsilon" in capsys.readouterr().err
        assert not runs.exists()

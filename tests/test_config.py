"""Config resolution and refusal: bad input is refused before compiling, naming the key."""


import pytest

import envs
from envs.biped import BipedEnv

from ptrl_jax import run as run_cli
from ptrl_jax.io.overrides import EXPERIMENTS_DIR, ConfigError, load_experiment


class TestOverrides:
    def test_scale_and_dotted_overrides(self):
        cfg = load_experiment("go2_to_xbot", ["scale=smoke", "target.ppo.learning_rate=3e-4", "seeds=3",
                                              "freeze_presets=[L2,scratch]", "source.env.commands.lin_vel_x=[0,1]"])
        assert cfg.scale == "smoke" and cfg.seeds == 3
        assert cfg.target.ppo.learning_rate == 3e-4
        assert cfg.freeze_presets == ("L2", "scratch")
        assert cfg.source.env.commands.lin_vel_x == (0.0, 1.0)
        assert cfg.source.ppo.num_envs == 32  # from the smoke section

    def test_freeze_ratios_follow_the_presets_as_variants(self):
        cfg = load_experiment("go2_to_xbot", ["freeze_presets=[L2,scratch]", "freeze_ratio=[0,0.25,1]"])
        assert cfg.variants == ("L2", "scratch", "rho0", "rho0.25", "rho1")
        only_ratios = load_experiment("go2_to_xbot", ["freeze_presets=[]", "freeze_ratio=[0.5]"])
        assert only_ratios.variants == ("rho0.5",)
        with pytest.raises(ConfigError, match="both empty"):
            load_experiment("go2_to_xbot", ["freeze_presets=[]", "freeze_ratio=[]"])

    def test_a_freeze_ratio_with_a_mode_is_a_preset_name_too(self):
        """``rho<r>@<mode>`` names a variant in freeze_presets as it does everywhere else."""
        cfg = load_experiment("go2_to_xbot", ["freeze_presets=[rho0.5@semantic_actor,L2,scratch]", "freeze_ratio=[]"])
        assert cfg.variants == ("rho0.5@semantic_actor", "L2", "scratch")
        with pytest.raises(ConfigError, match="freeze ratio must be in \\[0, 1\\], got 1.5"):
            load_experiment("go2_to_xbot", ["freeze_presets=[rho1.5@semantic]"])

    @pytest.mark.parametrize("arg,message", [
        ("ppo.learning_rate=1e-3", "did you mean '(source|target).ppo.learning_rate'"),
        ("target.ppo.learnin_rate=1e-3", "did you mean 'target.ppo.learning_rate'"),
        ("seeds=two", "seeds: expected an integer"),
        ("target.ppo.gamma=1.5", "gamma must be in"),
        ("target.ppo.num_minibatches=7", "not divisible"),
        ("scale=smoke target.ppo.final_noise_iterations=3", "final_noise_iterations must lie in \\[0, ppo.num_iterations=2\\]"),
        ("source.ppo.final_noise_std=0", "final_noise_std must be > 0"),
        ("freeze_presets=[L3]", "unknown \\['L3'\\]; choose from .* or rho<r>"),
        ("freeze_presets=[rhoX]", "unknown \\['rhoX'\\]"),
        ("freeze_ratio=[0.5,1.5]", "freeze_ratio: \\[1.5\\] outside \\[0, 1\\]"),
        ("freeze_ratio=[0.5,0.5]", "repeat a variant"),
        ("scale=huge", "scale must be one of"),
        ("transfer.critic_warmup=-1", "transfer.critic_warmup must be a whole number of iterations >= 0"),
        ("scale=smoke transfer.critic_warmup=2", "transfer.critic_warmup=2 must be below target.ppo.num_iterations=2"),
        ("target.robot=xbot", "did you mean 'xbot_l'"),
        ("report.semantic_preset=L2", "report.semantic_preset must name a semantic variant"),
        ("report.semantic_preset=L2@semantik", "report.semantic_preset: variant 'L2@semantik': unknown transfer mode"),
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
            load_experiment("go2_to_xbot", arg.split())

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


PAPER_TRANSFERS = ["go2_to_xbot", "mit_to_xbot", "xbot_to_mit", "xbot_to_cassie", "xbot_to_tron1",
                   "xbot_to_go2", "xbot_to_a1", "xbot_to_anymal_b", "xbot_to_anymal_c", "xbot_to_all"]


class TestPresets:
    @pytest.mark.parametrize("exp", PAPER_TRANSFERS)
    @pytest.mark.parametrize("scale", ["smoke", "cpu", "paper"])
    def test_every_paper_transfer_resolves_at_every_scale(self, exp, scale):
        cfg = load_experiment(exp, [f"scale={scale}"])
        assert cfg.name == exp and cfg.scale == scale
        src, _, tgt = exp.partition("_to_")
        alias = {"xbot": "xbot_l", "mit": "mit_humanoid"}
        assert cfg.source.robot == alias.get(src, src)
        if tgt != "all":
            assert list(cfg.targets) == [alias.get(tgt, tgt)]
        assert cfg.freeze_presets[:5] == ("none", "L1", "L2", "L1+L2", "scratch")
        # go2_to_xbot's smoke sweep (the CI sweep) adds semantic transfers; the paper's presets stay
        assert all(p.endswith("@semantic") for p in cfg.freeze_presets[5:])
        assert cfg.transfer.mode == "paper"

    @pytest.mark.parametrize("exp", sorted(p.stem for p in EXPERIMENTS_DIR.glob("*.yaml")
                                           if not p.stem.startswith("_")))
    @pytest.mark.parametrize("scale", ["smoke", "cpu", "paper"])
    def test_every_experiment_file_resolves_at_every_scale(self, exp, scale):
        """Every preset a user can name (`exp=<file>`) loads, with registered robots and known
        freeze presets, so a broken preset fails here rather than after a source stage."""
        from ptrl_jax.batch import batch_configs, is_batch

        if is_batch(exp):  # a batch resolves through each of its experiments
            configs, settings = batch_configs(exp, {"scale": scale})
            assert configs and settings["scale"] == scale
        else:
            configs = {exp: load_experiment(exp, [f"scale={scale}"])}
        for name, cfg in configs.items():
            assert cfg.name == name and cfg.scale == scale
            assert set(cfg.targets) <= set(envs.robot_names())
            assert cfg.freeze_presets and len(set(cfg.freeze_presets)) == len(cfg.freeze_presets)

    def test_xbot_to_all_fine_tunes_the_seven_other_robots(self):
        import envs

        cfg = load_experiment("xbot_to_all", ["scale=smoke"])
        assert sorted(cfg.targets) == sorted(r for r in envs.robot_names() if r != "xbot_l")
        for robot, stage in cfg.targets.items():
            assert stage.env == envs.default_config(robot) and stage.ppo == cfg.target.ppo

    @pytest.mark.parametrize("exp,robot,iterations", [("tron1_joystick", "tron1", (1400, 1400)),
                                                      ("xbot_l_joystick", "xbot_l", (1400, 700)),
                                                      ("mit_humanoid_joystick", "mit_humanoid", (800, 700)),
                                                      ("cassie_joystick", "cassie", (1000, 700))])
    def test_biped_joystick_trains_both_stages_on_the_turning_observation(self, exp, robot, iterations):
        """Both stages without the heading input and with the body's roll and pitch, so the
        randomized stage sees the observation its source learned on (docs/command_grid.md, stops
        56 to 58)."""
        cfg = load_experiment(exp, ["scale=cpu"])
        assert cfg.source.robot == robot and list(cfg.targets) == [robot]
        for stage in (cfg.source, cfg.targets[robot]):
            assert (stage.env.observe_heading, stage.env.euler_order) == (False, "zyx")
            assert stage.env.randomization.enabled is (stage is not cfg.source)
        assert (cfg.source.ppo.num_iterations, cfg.target.ppo.num_iterations) == iterations

    def test_extends_merges_scales_key_by_key(self):
        cfg = load_experiment("xbot_to_go2", ["scale=smoke", "target.ppo.num_iterations=3"])
        assert cfg.target.ppo.num_iterations == 3  # the command line wins
        assert cfg.source.ppo.num_envs == 16  # from _transfer's smoke section
        assert cfg.network.init_noise_std == 0.5  # from _transfer's top level

    def test_an_extends_cycle_is_refused(self, tmp_path):
        (tmp_path / "a.yaml").write_text(f"extends: {tmp_path / 'b.yaml'}\n")
        (tmp_path / "b.yaml").write_text(f"extends: {tmp_path / 'a.yaml'}\n")
        with pytest.raises(ConfigError, match="cycle: a -> b -> a"):
            load_experiment(str(tmp_path / "a.yaml"))

    @pytest.mark.parametrize("arg,message", [
        ("extra_targets=[go2,robodog]", "extra_targets: unknown robots \\['robodog'\\]"),
        ("extra_targets=[xbot_l]", "repeat a robot"),
    ])
    def test_bad_extra_targets_are_refused(self, arg, message):
        with pytest.raises(ConfigError, match=message):
            load_experiment("go2_to_xbot", arg.split())


class TestBipedFromScratch:
    @pytest.mark.parametrize("robot", [r for r in envs.robot_names() if envs.family(r) is BipedEnv])
    def test_trains_the_target_alone_with_its_ppo_settings(self, robot):
        cfg = load_experiment("biped_from_scratch", [f"target.robot={robot}"])
        assert list(cfg.targets) == [robot]
        assert cfg.freeze_presets == ("scratch",) and not cfg.trains_source
        ppo = cfg.target.ppo
        assert (ppo.entropy_coef, ppo.num_epochs, ppo.desired_kl) == (0.001, 2, 0.02)
        assert (ppo.num_envs, ppo.num_iterations) == (512, 700)
        assert (ppo.gamma, ppo.gae_lambda, ppo.clip_epsilon) == (0.998, 0.95, 0.2)  # the paper's


class TestCriticWarmupPerVariant:
    def test_transferring_variants_warm_up_and_scratch_does_not(self):
        import numpy as np

        from ptrl_jax.core.program import target_hparams

        cfg = load_experiment("go2_to_a1", ["transfer.critic_warmup=10",
                                            "freeze_presets=[L2,L2@semantic_actor,scratch]", "freeze_ratio=[0.5]"])
        hp = target_hparams(cfg)
        assert cfg.variants == ("L2", "L2@semantic_actor", "scratch", "rho0.5")
        np.testing.assert_array_equal(np.asarray(hp.critic_warmup), [10.0, 10.0, 0.0, 10.0])
        np.testing.assert_array_equal(np.asarray(hp.learning_rate), np.float32(cfg.target.ppo.learning_rate))
        assert float(cfg.source.ppo.hparams().critic_warmup) == 0.0  # the source stage never warms up
        default = target_hparams(load_experiment("go2_to_a1", []))
        assert not np.any(np.asarray(default.critic_warmup))

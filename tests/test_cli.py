"""The ``ptrl-jax`` console script and the commands' ``--help``."""

import os
import subprocess
import sys
from pathlib import Path

from ptrl_jax import cli


class TestConsoleScript:
    def test_help_lists_every_command(self, capsys):
        assert cli.main(["--help"]) == 0
        out = capsys.readouterr().out
        assert all(f"  {name}" in out for name in ("run", "evaluate", "export", "transfer", "table4"))

    def test_an_unknown_command_names_the_nearest(self, capsys):
        assert cli.main(["evalute", "ckpt=x"]) == 2
        assert "unknown command 'evalute'; did you mean 'evaluate'?" in capsys.readouterr().err

    def test_a_command_reaches_its_module(self, capsys):
        assert cli.main(["evaluate", "--help"]) == 0
        out = capsys.readouterr().out
        assert "walking check" in out and "keys: ckpt, vx" in out
        assert cli.main(["transfer", "target=a1"]) == 2  # the transfer module's own refusal
        assert "source= is required" in capsys.readouterr().err

    def test_run_help_lists_the_config_keys_with_defaults_and_docs(self, capsys):
        from ptrl_jax import run as run_cli

        assert run_cli.main(["--help"]) == 0
        out = capsys.readouterr().out
        assert "  report.threshold_metric = 'episode_reward'\n      The logged curve that time-to-threshold reads" in out
        assert "  transfer.noise_std = 0.0" in out and "  target.ppo.learning_rate = 0.001" in out

    def test_the_installed_script_runs(self):
        script = Path(sys.executable).parent / "ptrl-jax"
        assert script.is_file(), f"{script}: reinstall the package (pip install -e .) to get the console script"
        out = subprocess.run([str(script), "--help"], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0 and out.stdout.startswith("usage: ptrl-jax COMMAND"), out.stderr


class TestWheel:
    def test_the_wheel_carries_assets_and_presets_and_works_outside_the_checkout(self, tmp_path):
        """``pip wheel .`` holds the robots' MJCF and the presets (not the checkout's scripts), and
        the package unpacked from it, imported from another directory, finds both there."""
        import zipfile

        root = Path(__file__).resolve().parents[1]
        out = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path / "dist"),
                              str(root)], capture_output=True, text=True, timeout=600, cwd=tmp_path)
        assert out.returncode == 0, out.stderr[-3000:]
        (wheel,) = (tmp_path / "dist").glob("ptrl_jax-*.whl")
        names = zipfile.ZipFile(wheel).namelist()
        assert {"envs/assets/go2.xml", "envs/assets/xbot_l.xml", "ptrl_jax/presets/go2_to_xbot.yaml",
                "ptrl_jax/presets/_transfer.yaml", "ptrl_jax/presets/table4.yaml"} <= set(names)
        # every module of the checkout's packages, the core/ and io/ subpackages included
        root_modules = {str(p.relative_to(root)) for pkg in ("ptrl_jax", "envs") for p in (root / pkg).rglob("*.py")}
        assert "ptrl_jax/core/train.py" in root_modules and "ptrl_jax/io/resume.py" in root_modules
        assert root_modules <= set(names), sorted(root_modules - set(names))
        assert not [n for n in names if n.startswith(("ptrl_jax/presets/", "envs/assets/")) and n.endswith(".py")]
        site = tmp_path / "site"
        zipfile.ZipFile(wheel).extractall(site)
        probe = ("import envs, ptrl_jax.io.overrides as o; "
                 "cfg = o.load_experiment('go2_to_xbot', ['scale=smoke']); env = envs.make('xbot_l'); "
                 "print(o.EXPERIMENTS_DIR, envs.base.ASSETS_DIR, cfg.target.robot, env.action_size)")
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        got = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, cwd=elsewhere,
                             env={**os.environ, "PYTHONPATH": str(site)})
        assert got.returncode == 0, got.stderr[-3000:]
        presets, assets, robot, actions = got.stdout.split()
        assert presets == str(site / "ptrl_jax" / "presets") and assets == str(site / "envs" / "assets")
        assert robot == "xbot_l" and actions == "12"

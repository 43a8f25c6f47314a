"""The ``ptrl-jax`` console script and the commands' ``--help``."""

import subprocess
import sys
from pathlib import Path

from ptrl_jax import cli


class TestConsoleScript:
    def test_help_lists_every_command(self, capsys):
        assert cli.main(["--help"]) == 0
        out = capsys.readouterr().out
        assert all(f"  {name}" in out for name in ("run", "evaluate", "export", "transfer"))

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

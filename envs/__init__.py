"""Legged-robot environments on Brax + MuJoCo MJX. This package never imports the trainer.

    import envs
    env = envs.make("go2")                      # default config
    env = envs.make("go2", envs.default_config("go2"))
"""

import warnings

# Brax warns on every model load that its own pipelines are unmaintained; we only use its
# PipelineEnv structure on MuJoCo MJX, which is maintained.
warnings.filterwarnings("ignore", message="Brax System, piplines and environments", category=UserWarning)

from envs.registry import ROBOTS, default_config, make, robot_names  # noqa: E402

__all__ = ["ROBOTS", "default_config", "make", "robot_names"]

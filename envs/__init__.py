"""Legged-robot environments on Brax + MuJoCo MJX. This package never imports the trainer.

    import envs
    env = envs.make("go2")                      # default config
    env = envs.make("go2", envs.default_config("go2"))
"""

from envs.registry import ROBOTS, default_config, make, robot_names

__all__ = ["ROBOTS", "default_config", "make", "robot_names"]

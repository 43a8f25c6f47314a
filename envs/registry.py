"""Robot name -> (family, default config). Adding a robot is one asset plus one entry here."""

from __future__ import annotations

import difflib
from typing import NamedTuple

from envs.base import LeggedEnv, LocomotionConfig
from envs.biped import CASSIE_CONFIG, MIT_HUMANOID_CONFIG, TRON1_CONFIG, XBOT_L_CONFIG, BipedEnv
from envs.quadruped import A1_CONFIG, ANYMAL_B_CONFIG, ANYMAL_C_CONFIG, GO2_CONFIG, QuadrupedEnv


class RobotEntry(NamedTuple):
    family: type[LeggedEnv]
    config: LocomotionConfig
    description: str


ROBOTS: dict[str, RobotEntry] = {
    "go2": RobotEntry(QuadrupedEnv, GO2_CONFIG, "Unitree Go2 quadruped, 12 DOF"),
    "a1": RobotEntry(QuadrupedEnv, A1_CONFIG, "Unitree A1 quadruped, 12 DOF"),
    "anymal_b": RobotEntry(QuadrupedEnv, ANYMAL_B_CONFIG, "ANYbotics ANYmal B quadruped, 12 DOF"),
    "anymal_c": RobotEntry(QuadrupedEnv, ANYMAL_C_CONFIG, "ANYbotics ANYmal C quadruped, 12 DOF"),
    "xbot_l": RobotEntry(BipedEnv, XBOT_L_CONFIG, "RobotEra XBot-L humanoid legs, 12 DOF"),
    "mit_humanoid": RobotEntry(BipedEnv, MIT_HUMANOID_CONFIG, "MIT Humanoid legs, 10 DOF, arms fixed"),
    "cassie": RobotEntry(BipedEnv, CASSIE_CONFIG, "Agility Cassie biped, 12-DOF open tree"),
    "tron1": RobotEntry(BipedEnv, TRON1_CONFIG, "LimX TRON1 point-foot biped, 6 DOF"),
}


def robot_names() -> list[str]:
    return list(ROBOTS)


def _entry(robot: str) -> RobotEntry:
    if robot not in ROBOTS:
        near = difflib.get_close_matches(robot, ROBOTS, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else ""
        raise ValueError(f"unknown robot {robot!r}{hint} Known robots: {', '.join(ROBOTS)}")
    return ROBOTS[robot]


def family(robot: str) -> type[LeggedEnv]:
    """The robot's env class: ``QuadrupedEnv`` or ``BipedEnv``."""
    return _entry(robot).family


def default_config(robot: str) -> LocomotionConfig:
    return _entry(robot).config


def make(robot: str, config: LocomotionConfig | None = None) -> LeggedEnv:
    entry = _entry(robot)
    config = entry.config if config is None else config
    if not isinstance(config, type(entry.config)):
        raise TypeError(f"robot {robot!r} needs a {type(entry.config).__name__}, got {type(config).__name__}")
    return entry.family(config)

"""``tensorboard=true``: metrics rows as TensorBoard event files, read back record by record."""

import struct
from pathlib import Path

import pytest

from ptrl_jax.io.tensorboard import write_events


def read_scalars(folder: Path) -> dict[str, list[tuple[int, float, float]]]:
    """{tag: [(step, value, wall_time)]} from the TFRecord event files in ``folder``."""
    from tensorboardX.proto import event_pb2

    out: dict[str, list] = {}
    for path in sorted(folder.glob("events.out.tfevents.*")):
        data = path.read_bytes()
        i = 0
        while i < len(data):
            (length,) = struct.unpack("<Q", data[i:i + 8])
            event = event_pb2.Event.FromString(data[i + 12:i + 12 + length])
            i += 12 + length + 4  # length, its CRC, the record, its CRC
            for v in event.summary.value:
                out.setdefault(v.tag, []).append((event.step, v.simple_value, event.wall_time))
    return out


ROWS = [
    {"stage": "target", "robot": "a1", "preset": "L2@semantic", "seed": 1, "iteration": i, "env_steps": 100 * i,
     "wall_time_s": 2.0 * i, "episode_reward": 0.5 * i, "episode_reward/tracking_lin_vel": float(i), "kl": float("nan")}
    for i in (1, 2)
] + [{"stage": "source", "robot": "go2", "preset": "source", "seed": 0, "iteration": 1, "env_steps": 64,
      "wall_time_s": 1.0, "episode_reward": 3.0}]


class TestTensorBoard:
    def test_one_folder_per_run_and_every_numeric_column(self, tmp_path):
        folders = write_events(tmp_path, ROWS, start_time=1000.0)
        assert sorted(f.name for f in folders) == ["source_go2_source_seed0", "target_a1_L2_at_semantic_seed1"]
        target = read_scalars(tmp_path / "target_a1_L2_at_semantic_seed1")
        assert set(target) == {"episode_reward", "episode_reward/tracking_lin_vel"}  # kl is NaN: left out
        assert target["episode_reward"] == [(100, 0.5, pytest.approx(1002.0)), (200, 1.0, pytest.approx(1004.0))]
        assert [v for _, v, _ in target["episode_reward/tracking_lin_vel"]] == [1.0, 2.0]
        assert read_scalars(tmp_path / "source_go2_source_seed0")["episode_reward"][0][:2] == (64, 3.0)

    def test_the_config_key(self):
        from ptrl_jax.io.overrides import build_config

        assert build_config({"tensorboard": "true"}).tensorboard is True

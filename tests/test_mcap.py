"""MCAP for Foxglove: a rollout written and read back with the mcap reader."""

from collections import Counter

import numpy as np

import envs
from ptrl_jax.io.mcap_log import read_messages, write_rollout


def short_rollout(steps=12):
    env = envs.LocomotionGymEnv("go2")
    env.reset(seed=0, options={"command": (0.5, 0.0, 0.1)})
    qpos, qvel, cmd, terms = [], [], [], {}
    for t in range(steps):
        _, _, _, _, info = env.step(np.full(12, 0.1 * np.sin(t), np.float32))
        qpos.append(env.data.qpos.copy())
        qvel.append(env.data.qvel.copy())
        cmd.append(info["command"])
        for k, v in info.items():
            if k.startswith("reward/"):
                terms.setdefault(k, []).append(v)
    return env, np.array(qpos), np.array(qvel), np.array(cmd), {k: np.array(v) for k, v in terms.items()}


class TestMcapRollout:
    def test_messages_read_back(self, tmp_path):
        env, qpos, qvel, cmd, terms = short_rollout()
        path = tmp_path / "rollout.mcap"
        counts = write_rollout(path, env.model, env.config.ctrl_dt, qpos, qvel, cmd, terms)
        msgs = list(read_messages(path))

        by_topic = Counter(topic for topic, *_ in msgs)
        assert by_topic == {"/scene": 1, "/tf": 12, "/joint_states": 12, "/command": 12, "/reward": 12}
        assert dict(by_topic) == counts
        schemas = {topic: schema for topic, schema, *_ in msgs}
        assert schemas["/tf"] == "foxglove.FrameTransforms" and schemas["/scene"] == "foxglove.SceneUpdate"

        tf = [m for topic, _, _, m in msgs if topic == "/tf"]
        last = {t["child_frame_id"]: t for t in tf[-1]["transforms"]}
        assert len(last) == env.model.nbody - 1 and "base" in last
        base = last["base"]
        # MuJoCo (w, x, y, z) -> Foxglove (x, y, z, w); the free joint's qpos is the base pose.
        w, x, y, z = qpos[-1, 3:7]
        r = base["rotation"]
        np.testing.assert_allclose([r["x"], r["y"], r["z"], r["w"]], [x, y, z, w], atol=1e-9)
        np.testing.assert_allclose([base["translation"][k] for k in "xyz"], qpos[-1, :3], atol=1e-9)

        joints = [m for topic, _, _, m in msgs if topic == "/joint_states"]
        assert len(joints[0]["name"]) == 12
        np.testing.assert_allclose(joints[5]["position"], qpos[5, 7:], atol=1e-9)

        commands = [m for topic, _, _, m in msgs if topic == "/command"]
        assert commands[0]["vx_cmd"] == 0.5 and commands[0]["yaw_rate_cmd"] == np.float32(0.1)

        rewards = [m for topic, _, _, m in msgs if topic == "/reward"]
        assert set(rewards[3]["terms"]) == set(terms)
        assert abs(rewards[3]["total"] - sum(v[3] for v in terms.values())) < 1e-6

        scene = next(m for topic, _, _, m in msgs if topic == "/scene")
        n_prims = sum(len(e["cubes"]) + len(e["spheres"]) + len(e["cylinders"]) for e in scene["entities"])
        assert n_prims >= env.model.ngeom  # every geom drawn (capsules as cylinders)

        times = [t for topic, _, t, _ in msgs if topic == "/tf"]
        assert times == sorted(times) and times[1] - times[0] == round(env.config.ctrl_dt * 1e9)


class TestFoxgloveLayout:
    def test_layout_reads_the_topics_we_write(self):
        import json
        import re
        from pathlib import Path

        from ptrl_jax.io.mcap_log import TOPICS

        text = (Path(__file__).resolve().parents[1] / "experiments" / "foxglove_layout.json").read_text()
        layout = json.loads(text)
        assert "3D!robot" in layout["configById"]
        used = set(re.findall(r'"(/[a-z_]+)[."]', text))
        assert used and used <= set(TOPICS), used - set(TOPICS)

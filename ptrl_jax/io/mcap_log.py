"""Write a rollout to an ``.mcap`` file that Foxglove opens directly (JSON encoding).

Channels (one message per control step unless noted):

    /tf             foxglove.FrameTransforms   world -> every body (poses from MuJoCo kinematics)
    /scene          foxglove.SceneUpdate       the model's primitive geoms, each locked to its body
                                               (written once, at the first step)
    /joint_states   ptrl.JointStates           joint names, positions, velocities, torques
    /command        ptrl.Command               commanded and measured vx, vy, yaw rate
    /reward         ptrl.RewardTerms           every weighted reward term and their sum

Body poses are recomputed here from ``qpos`` with ``mujoco.mj_kinematics``, so the same writer
serves MJX rollouts and MuJoCo C rollouts. Quaternions are converted from MuJoCo's (w, x, y, z)
to Foxglove's (x, y, z, w). ``experiments/foxglove_layout.json`` is a layout for these topics.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import mujoco
import numpy as np
from mcap.writer import Writer

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}


def _primitive(extra: Mapping[str, Any]) -> dict:
    return {"type": "array", "items": {"type": "object", "properties": {"pose": _POSE, "color": _COLOR, **extra}}}


SCHEMAS: dict[str, dict] = {
    "foxglove.FrameTransforms": {
        "type": "object",
        "properties": {
            "transforms": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME, "parent_frame_id": {"type": "string"},
                        "child_frame_id": {"type": "string"}, "translation": _VEC3, "rotation": _QUAT,
                    },
                },
            }
        },
    },
    "foxglove.SceneUpdate": {
        "type": "object",
        "properties": {
            "deletions": {"type": "array", "items": {"type": "object"}},
            "entities": {
                "type": "array",
                "items": {
                    "type": "object",
                    "properties": {
                        "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
                        "lifetime": _TIME, "frame_locked": {"type": "boolean"},
                        "metadata": {"type": "array", "items": {"type": "object"}},
                        "cubes": _primitive({"size": _VEC3}),
                        "spheres": _primitive({"size": _VEC3}),
                        "cylinders": _primitive({"size": _VEC3, "bottom_scale": {"type": "number"},
                                                 "top_scale": {"type": "number"}}),
                        "arrows": {"type": "array"}, "lines": {"type": "array"}, "triangles": {"type": "array"},
                        "texts": {"type": "array"}, "models": {"type": "array"},
                    },
                },
            },
        },
    },
    "ptrl.JointStates": {
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            "name": {"type": "array", "items": {"type": "string"}},
            "position": {"type": "array", "items": {"type": "number"}},
            "velocity": {"type": "array", "items": {"type": "number"}},
            "effort": {"type": "array", "items": {"type": "number"}},
        },
    },
    "ptrl.Command": {
        "type": "object",
        "properties": {
            "timestamp": _TIME,
            **{k: {"type": "number"} for k in ("vx_cmd", "vy_cmd", "yaw_rate_cmd", "vx", "vy", "yaw_rate")},
        },
    },
    "ptrl.RewardTerms": {
        "type": "object",
        "properties": {"timestamp": _TIME, "total": {"type": "number"},
                       "terms": {"type": "object", "additionalProperties": {"type": "number"}}},
    },
}

TOPICS = {
    "/tf": "foxglove.FrameTransforms",
    "/scene": "foxglove.SceneUpdate",
    "/joint_states": "ptrl.JointStates",
    "/command": "ptrl.Command",
    "/reward": "ptrl.RewardTerms",
}


_BOX, _SPHERE, _CYLINDER, _CAPSULE, _PLANE, _ELLIPSOID = (
    int(getattr(mujoco.mjtGeom, f"mjGEOM_{n}")) for n in ("BOX", "SPHERE", "CYLINDER", "CAPSULE", "PLANE", "ELLIPSOID")
)


def _stamp(t: float) -> dict[str, int]:
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _quat_xyzw(q_wxyz: np.ndarray) -> dict[str, float]:
    w, x, y, z = (float(v) for v in q_wxyz)
    return {"x": x, "y": y, "z": z, "w": w}


def _vec(v: Sequence[float]) -> dict[str, float]:
    return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}


def _body_name(model: mujoco.MjModel, i: int) -> str:
    return model.body(i).name or f"body_{i}"


def scene_entities(model: mujoco.MjModel, t: float) -> list[dict]:
    """One entity per body, holding its primitive geoms at their body-local poses."""
    by_body: dict[int, dict[str, list]] = {}
    for g in range(model.ngeom):
        body = int(model.geom_bodyid[g])
        kind = int(model.geom_type[g])
        size = model.geom_size[g]
        rgba = model.geom_rgba[g]
        color = {"r": float(rgba[0]), "g": float(rgba[1]), "b": float(rgba[2]), "a": float(rgba[3])}
        pose = {"position": _vec(model.geom_pos[g]), "orientation": _quat_xyzw(model.geom_quat[g])}
        prims = by_body.setdefault(body, {"cubes": [], "spheres": [], "cylinders": []})
        if kind == _BOX:
            prims["cubes"].append({"pose": pose, "size": _vec(2 * size), "color": color})
        elif kind == _SPHERE:
            prims["spheres"].append({"pose": pose, "size": _vec([2 * size[0]] * 3), "color": color})
        elif kind in (_CYLINDER, _CAPSULE):
            length = 2 * size[1] + (2 * size[0] if kind == _CAPSULE else 0.0)
            prims["cylinders"].append({"pose": pose, "size": _vec([2 * size[0], 2 * size[0], length]),
                                       "bottom_scale": 1.0, "top_scale": 1.0, "color": color})
        elif kind == _PLANE:
            prims["cubes"].append({"pose": pose, "size": _vec([20.0, 20.0, 0.001]), "color": color})
        elif kind == _ELLIPSOID:
            prims["spheres"].append({"pose": pose, "size": _vec(2 * size), "color": color})
    entities = []
    for body, prims in sorted(by_body.items()):
        name = "world" if body == 0 else _body_name(model, body)
        entities.append({
            "timestamp": _stamp(t), "frame_id": name, "id": f"geoms/{name}", "lifetime": _stamp(0.0),
            "frame_locked": True, "metadata": [], "arrows": [], "lines": [], "triangles": [], "texts": [],
            "models": [], **prims,
        })
    return entities


def write_rollout(
    path: Path,
    model: mujoco.MjModel,
    dt: float,
    qpos: np.ndarray,
    qvel: np.ndarray,
    command: np.ndarray,
    reward_terms: Mapping[str, np.ndarray],
    torques: np.ndarray | None = None,
) -> dict[str, int]:
    """Write ``T`` steps (``qpos [T, nq]``, ``qvel [T, nv]``, ``command [T, 3]``, each reward
    term ``[T]``) to ``path``. Returns the message count per topic."""
    qpos, qvel, command = (np.asarray(x, np.float64) for x in (qpos, qvel, command))
    steps = qpos.shape[0]
    if qvel.shape[0] != steps or command.shape[0] != steps:
        raise ValueError(f"qpos, qvel and command need the same number of steps: "
                         f"{qpos.shape[0]}, {qvel.shape[0]}, {command.shape[0]}")
    data = mujoco.MjData(model)
    joint_names = [model.joint(j).name for j in range(model.njnt) if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_FREE]
    counts = {topic: 0 for topic in TOPICS}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")  # written whole, then renamed: never half a file
    with open(tmp, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="ptrl_jax")
        channels = {}
        for topic, schema_name in TOPICS.items():
            schema_id = writer.register_schema(name=schema_name, encoding="jsonschema",
                                               data=json.dumps(SCHEMAS[schema_name]).encode())
            channels[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=schema_id)

        def put(topic: str, t: float, msg: dict) -> None:
            ns = int(round(t * 1e9))
            writer.add_message(channels[topic], log_time=ns, publish_time=ns, data=json.dumps(msg).encode())
            counts[topic] += 1

        for i in range(steps):
            t = (i + 1) * dt
            data.qpos[:] = qpos[i]
            mujoco.mj_kinematics(model, data)
            if i == 0:
                put("/scene", t, {"deletions": [], "entities": scene_entities(model, t)})
            put("/tf", t, {"transforms": [
                {"timestamp": _stamp(t), "parent_frame_id": "world", "child_frame_id": _body_name(model, b),
                 "translation": _vec(data.xpos[b]), "rotation": _quat_xyzw(data.xquat[b])}
                for b in range(1, model.nbody)
            ]})
            put("/joint_states", t, {
                "timestamp": _stamp(t), "name": joint_names,
                "position": [float(x) for x in qpos[i, 7:]], "velocity": [float(x) for x in qvel[i, 6:]],
                "effort": [] if torques is None else [float(x) for x in np.asarray(torques)[i]],
            })
            # Measured velocity in the base frame, as the env's tracking rewards see it.
            base_rot = data.xmat[1].reshape(3, 3)
            v_base = base_rot.T @ qvel[i, :3]
            put("/command", t, {
                "timestamp": _stamp(t), "vx_cmd": float(command[i, 0]), "vy_cmd": float(command[i, 1]),
                "yaw_rate_cmd": float(command[i, 2]), "vx": float(v_base[0]), "vy": float(v_base[1]),
                "yaw_rate": float(qvel[i, 5]),
            })
            terms = {k: float(np.asarray(v)[i]) for k, v in reward_terms.items()}
            put("/reward", t, {"timestamp": _stamp(t), "total": float(sum(terms.values())), "terms": terms})
        writer.finish()
    os.replace(tmp, path)
    return counts


def read_messages(path: Path) -> Iterable[tuple[str, str, int, dict]]:
    """(topic, schema name, log time ns, decoded JSON) for every message: for tests and tools."""
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            yield channel.topic, schema.name, message.log_time, json.loads(message.data)

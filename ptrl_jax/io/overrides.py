"""``key=value`` overrides over frozen dataclasses, and experiment presets from YAML.

Used alike by the CLI, notebooks and sweeps::

    cfg = load_experiment("go2_to_xbot", ["scale=smoke", "ppo.learning_rate=3e-4"])

Unknown keys, wrong types and impossible values fail here, before anything compiles, with a
message that names the key and the nearest valid one.
"""

from __future__ import annotations

import dataclasses
import difflib
import typing
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

import envs
from ptrl_jax.config import SCALES, ConfigError, ExperimentConfig, StageConfig

def _experiments_dir() -> Path:
    """The experiment presets: ``ptrl_jax/presets/`` in an installed wheel (pyproject.toml ships
    experiments/*.yaml there), else the checkout's ``experiments/``."""
    package = Path(__file__).resolve().parents[1]  # ptrl_jax/
    packaged = package / "presets"
    return packaged if packaged.is_dir() else package.parent / "experiments"


EXPERIMENTS_DIR = _experiments_dir()


def valid_keys(obj: Any, prefix: str = "") -> list[str]:
    keys = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        path = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            keys.extend(valid_keys(value, path + "."))
        else:
            keys.append(path)
    return keys


def coerce(value: Any, annotation: Any, key: str) -> Any:
    """``value`` (often CLI text) as ``annotation``'s type; a ConfigError names ``key``."""
    origin = typing.get_origin(annotation)
    if annotation is Any:
        return value
    if origin is typing.Union or str(origin) == "<class 'types.UnionType'>":
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if value is None or (isinstance(value, str) and value.lower() in ("none", "null")):
            return None
        return coerce(value, args[0], key)
    if origin is tuple:
        args = typing.get_args(annotation)
        if isinstance(value, str):
            value = yaml.safe_load(value) if value.strip().startswith("[") else [v for v in value.split(",") if v]
        if not isinstance(value, (list, tuple)):
            value = [value]
        elem = args[0] if args else Any
        if len(args) == 2 and args[1] is Ellipsis or len(args) <= 1:
            return tuple(coerce(v, elem, key) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)} ({value!r})")
        return tuple(coerce(v, a, key) for v, a in zip(value, args))
    if annotation is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "1", "yes", "on", "false", "0", "no", "off"):
            return value.lower() in ("true", "1", "yes", "on")
        raise ConfigError(f"{key}: expected true or false, got {value!r}")
    if annotation is int:
        if isinstance(value, bool):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected an integer, got {value!r}") from None
        if f != int(f):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return int(f)
    if annotation is float:
        try:
            return float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"{key}: expected a number, got {value!r}") from None
    if annotation is str:
        return str(value)
    return value


def _suggest(key: str, options: Iterable[str]) -> str:
    near = difflib.get_close_matches(key, list(options), n=1, cutoff=0.5)
    return f"; did you mean {near[0]!r}?" if near else ""


def apply_overrides(obj: Any, overrides: Mapping[str, Any], prefix: str = "") -> Any:
    """Return a copy of the dataclass ``obj`` with dotted-key overrides applied."""
    grouped: dict[str, dict[str, Any]] = {}
    direct: dict[str, Any] = {}
    for key, value in overrides.items():
        head, _, rest = key.partition(".")
        if rest:
            grouped.setdefault(head, {})[rest] = value
        else:
            direct[head] = value
    fields = {f.name: f for f in dataclasses.fields(obj)}
    hints = typing.get_type_hints(type(obj))
    all_keys = valid_keys(obj, prefix)
    changes: dict[str, Any] = {}
    for head in [*direct, *grouped]:
        if head not in fields:
            full = prefix + head + ("." + next(iter(grouped[head])) if head in grouped else "")
            raise ConfigError(f"unknown key {full!r}{_suggest(full, all_keys)}")
    for head, value in direct.items():
        current = getattr(obj, head)
        if dataclasses.is_dataclass(current):
            raise ConfigError(f"{prefix}{head} is a group; set one of its keys, e.g. {valid_keys(current, prefix + head + '.')[0]!r}")
        changes[head] = coerce(value, hints[head], prefix + head)
    for head, sub in grouped.items():
        current = changes.get(head, getattr(obj, head))
        if not dataclasses.is_dataclass(current):
            full = prefix + head + "." + next(iter(sub))
            raise ConfigError(f"unknown key {full!r}: {prefix}{head} has no sub-keys{_suggest(full, all_keys)}")
        changes[head] = apply_overrides(current, sub, prefix + head + ".")
    try:
        return dataclasses.replace(obj, **changes)
    except (ValueError, TypeError) as e:
        raise ConfigError(f"{prefix or 'config'}: {e}") from None


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def parse_cli(args: Iterable[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for arg in args:
        if "=" not in arg:
            raise ConfigError(f"arguments are key=value; got {arg!r} (e.g. exp=go2_to_xbot scale=smoke)")
        k, v = arg.split("=", 1)
        out[k.strip()] = v.strip()
    return out


def parse_known_cli(args: Iterable[str], known: Iterable[str]) -> dict[str, str]:
    """``parse_cli`` for a command with a fixed set of keys (evaluate, transfer, table4): a key
    outside ``known`` is refused, naming the known ones."""
    known = tuple(known)
    out = parse_cli(args)
    unknown = sorted(set(out) - set(known))
    if unknown:
        raise ConfigError(f"unknown argument(s) {unknown}; known: {', '.join(known)}")
    return out


def preset_path(name: str) -> Path:
    p = Path(name)
    if p.suffix in (".yaml", ".yml") and p.is_file():
        return p
    candidate = EXPERIMENTS_DIR / f"{name}.yaml"
    if candidate.is_file():
        return candidate
    known = sorted(q.stem for q in EXPERIMENTS_DIR.glob("*.yaml") if not q.stem.startswith("_"))
    raise ConfigError(f"unknown experiment {name!r}{_suggest(name, known)} Known: {', '.join(known)}")


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def read_preset(exp: str, _seen: tuple[Path, ...] = ()) -> dict:
    """A preset file as a nested dict, with ``extends: <other preset>`` (or a list of them,
    merged in order) resolved: the file's own keys win, nested sections such as ``scales`` merge
    key by key."""
    path = preset_path(exp).resolve()
    if path in _seen:
        chain = " -> ".join(p.stem for p in (*_seen, path))
        raise ConfigError(f"experiment presets extend each other in a cycle: {chain}")
    with open(path) as f:
        preset = yaml.safe_load(f) or {}
    parents = preset.pop("extends", None)
    if parents is None:
        return preset
    base: dict = {}
    for parent in parents if isinstance(parents, list) else [parents]:
        base = _deep_merge(base, read_preset(str(parent), (*_seen, path)))
    return _deep_merge(base, preset)


def load_experiment(exp: str, overrides: Mapping[str, Any] | Iterable[str] = ()) -> ExperimentConfig:
    """Preset file (and what it extends) -> its scale section -> overrides, into a validated
    ExperimentConfig."""
    if not isinstance(overrides, Mapping):
        overrides = parse_cli(overrides)
    overrides = dict(overrides)
    preset = read_preset(exp)
    if "batch" in preset:
        raise ConfigError(f"exp={exp} is a batch of experiments ({', '.join(map(str, preset['batch']))}): "
                          f"run it with python -m ptrl_jax.run exp={exp} (ptrl_jax.batch.run_batch)")
    scales = preset.pop("scales", {}) or {}
    scale = str(overrides.pop("scale", preset.pop("scale", "cpu")))
    if scale not in SCALES:
        raise ConfigError(f"scale must be one of {SCALES}, got {scale!r}{_suggest(scale, SCALES)}")
    merged = {**flatten(preset), **flatten(scales.get(scale, {}) or {}), **overrides}
    merged.setdefault("name", Path(exp).stem)
    merged["scale"] = scale
    return build_config(merged)


def build_config(flat: Mapping[str, Any]) -> ExperimentConfig:
    flat = dict(flat)
    if "transfer" in flat:  # transfer=semantic is short for transfer.mode=semantic
        flat["transfer.mode"] = flat.pop("transfer")
    base = ExperimentConfig()
    stages = {}
    for stage in ("source", "target"):
        robot = str(flat.pop(f"{stage}.robot", getattr(base, stage).robot))
        try:
            env_cfg = envs.default_config(robot)
        except ValueError as e:
            raise ConfigError(f"{stage}.robot: {e}") from None
        stages[stage] = StageConfig(robot=robot, ppo=getattr(base, stage).ppo, env=env_cfg)
    cfg = dataclasses.replace(base, **stages)
    return apply_overrides(cfg, flat)


def to_dict(obj: Any) -> Any:
    """A YAML-friendly nested dict of a config."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [to_dict(v) for v in obj]
    return obj


def field_docs(cls: type) -> dict[str, str]:
    """Each field's docstring of a dataclass (the string literal right after the field), read from
    its source: {name: docstring}."""
    import ast
    import inspect
    import textwrap

    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs = {}
    for node, after in zip(body, body[1:]):
        if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(after, ast.Expr)
                and isinstance(after.value, ast.Constant) and isinstance(after.value.value, str)):
            docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def config_keys(cls: type = None, prefix: str = "") -> list[tuple[str, str, str]]:
    """Every dotted key of the experiment config: (key, default, docstring), for ``--help``.
    Robot env configs (``source.env``, ``target.env``) depend on the robot and are listed as one
    key each."""
    from ptrl_jax.config import ExperimentConfig

    cls = cls or ExperimentConfig
    docs = field_docs(cls)
    instance = cls()
    out = []
    for f in dataclasses.fields(cls):
        value = getattr(instance, f.name)
        if dataclasses.is_dataclass(value):
            out += config_keys(type(value), f"{prefix}{f.name}.")
        else:
            out.append((f"{prefix}{f.name}", repr(value), docs.get(f.name, "")))
    return out


def format_keys(width: int = 100) -> str:
    """The config keys as help text: key, default, then the docstring's first sentence."""
    lines = []
    for key, default, doc in config_keys():
        first = doc.split(". ")[0].rstrip(".")
        lines.append(f"  {key} = {default}")
        if first:
            lines.append(f"      {first[:width - 6]}")
    return "\n".join(lines)

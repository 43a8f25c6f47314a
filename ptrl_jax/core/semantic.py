"""The semantic transfer: carry what two robots share through the whole agent.

The paper's transfer (``freeze.transfer``) copies the actor's hidden layers L1 and L2 and starts
the input layer, output layer, log-std, normaliser and critic fresh, so L1 first reads a random
projection of the target's observation. This one maps instead, from the envs' declarations
(``envs.semantics``: named observation entries, joint roles and axis signs):

- **Joints.** Each target joint takes the source joint of the same kind on the corresponding
  limb (``LIMB_MAPS``); ``TransferConfig.joint_map`` overrides any pair. The factor between them
  is the product of their axis signs times the ratio of action scales, so a mapped action asks
  for the same physical rotation, about the same canonical axis, of the joint's target angle.
  With ``knee="flexion"`` a knee pair's sign is the product of their flexion directions
  instead, so a knee that points the other way (ANYmal's hind knees from Go2's) flexes where
  its source flexes rather than extending.
- **Observation entries.** A target entry takes the source entry of the same quantity and
  component (joints and feet through the joint and limb maps; stacked frames by age). Its raw
  value relates to the source's by ``factor`` (signs and scales); entries without a counterpart
  (a biped's gait clock, an older stacked frame when the source has one frame, a joint the
  source lacks) are unmatched.
- **Parameters.** Input layer (actor and critic): a matched entry's weight row is the source's
  row times the sign of its factor, divided by the number of target entries that read the same
  source entry (two quadruped legs from one biped leg share it); unmatched rows are zero, so at
  iteration 0 the target computes what the source would from the shared inputs. Hidden layers
  and the critic's output layer are copied. Output layer, bias and log-std: a mapped joint's
  column is the source's times its factor (log-std plus log|factor|); an unmapped joint's
  column is the fresh one times ``UNMAPPED_OUTPUT_SCALE`` with zero bias, and its log-std the
  mean of the mapped ones.
- **Normaliser.** Matched entries carry the source's statistics converted by the factor
  (mean times factor, variance times factor squared) and the source's count; unmatched entries
  get mean 0 and variance 1 (their weights are zero at first).

Everything is indexing with static numpy maps, so ``apply`` traces inside the one program.
"""

from __future__ import annotations

import difflib
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from envs import semantics
from ptrl_jax.core import normalization
from ptrl_jax.core.types import Params

UNMAPPED_OUTPUT_SCALE = 0.01
"""Fresh output columns of joints with no counterpart start at this share of their init."""

# target limb -> source limb, per (source family, target family).
LIMB_MAPS: dict[tuple[str, str], dict[str, str]] = {
    # A biped's legs take a quadruped's hind legs: they carry the body's weight and push it
    # forward, and their hip pitch and knee swing in the sagittal plane as a biped's do.
    ("quadruped", "biped"): {"L": "RL", "R": "RR"},
    # A quadruped's legs take the biped leg on their side (front and hind alike). Each side's two
    # legs then start in phase, a pace rather than a trot; the fine-tuning has to find the trot.
    ("biped", "quadruped"): {"FL": "L", "RL": "L", "FR": "R", "RR": "R"},
}


class EntryMap(NamedTuple):
    """How one observation vector of the target reads the source's (numpy, static)."""

    source_index: np.ndarray
    """[n_target] index of the counterpart source entry, -1 where unmatched."""
    factor: np.ndarray
    """[n_target] target raw value = factor * source raw value (1 where unmatched)."""
    weight: np.ndarray
    """[n_target] multiplier of the source's input-weight row: sign(factor) / readers."""


class TransferMap(NamedTuple):
    """Everything the semantic transfer of one (source, target) pair needs."""

    obs: dict[str, EntryMap]
    """Per observation key ("state", "privileged_state")."""
    joint_source: np.ndarray
    """[target joints] index of the source joint, -1 where unmapped."""
    joint_factor: np.ndarray
    """[target joints] target action = factor * source action (1 where unmapped)."""
    joint_pairs: tuple[tuple[str, str, float], ...]
    """(target joint, source joint or '', factor): the map in words, for metadata and docs."""
    limbs: dict[str, str]
    """target limb -> source limb."""

    def describe(self) -> dict[str, Any]:
        """A JSON-friendly summary (checkpoint metadata, report)."""
        return {
            "joints": [{"target": t, "source": s or None, "factor": round(float(f), 6)} for t, s, f in self.joint_pairs],
            "limbs": dict(self.limbs),
            "matched_entries": {k: int((m.source_index >= 0).sum()) for k, m in self.obs.items()},
            "entries": {k: int(m.source_index.size) for k, m in self.obs.items()},
        }


def limb_map(source_env, target_env) -> dict[str, str]:
    fam = (source_env.family_name, target_env.family_name)
    target_limbs = sorted({r.limb for r in target_env.joint_roles})
    if fam[0] == fam[1]:
        return {limb: limb for limb in target_limbs}
    if fam not in LIMB_MAPS:
        raise ValueError(f"no limb map from the {fam[0]} family to the {fam[1]} family; add one to "
                         f"ptrl_jax.core.semantic.LIMB_MAPS or give transfer.joint_map")
    return dict(LIMB_MAPS[fam])


def _nearest(name: str, options) -> str:
    near = difflib.get_close_matches(name, list(options), n=1, cutoff=0.4)
    return f"; did you mean {near[0]!r}?" if near else ""


def _require_roles(env, which: str) -> None:
    if not env.joint_roles:
        raise ValueError(f"the {which} robot ({env.config.asset}) declares no joint_roles, so a semantic "
                         f"transfer cannot map its joints (envs.semantics; LocomotionConfig.joint_roles)")


def joint_correspondence(source_env, target_env, joint_map: tuple[str, ...] = (),
                         knee: str = "axis") -> tuple[np.ndarray, np.ndarray, dict]:
    """(source joint per target joint or -1, sign per target joint, limb map). ``joint_map``
    entries ``"<target joint>:<source joint>"`` override the role-based pairs; a source name
    prefixed with ``-`` flips the sign again, and ``none`` leaves the target joint unmapped.
    ``knee="axis"`` signs knees by their axes (the same rotation), ``"flexion"`` by their flexion
    directions (flexion maps to flexion; ``envs.semantics.knee_flexion_signs``)."""
    if knee not in semantics.KNEE_CONVENTIONS:
        raise ValueError(f"transfer.knee must be one of {list(semantics.KNEE_CONVENTIONS)}, got {knee!r}")
    _require_roles(source_env, "source")
    _require_roles(target_env, "target")
    limbs = limb_map(source_env, target_env)
    by_role = {(r.limb, r.kind): i for i, r in enumerate(source_env.joint_roles)}
    src = np.full(target_env.num_joints, -1)
    extra_sign = np.ones(target_env.num_joints)
    for j, role in enumerate(target_env.joint_roles):
        src[j] = by_role.get((limbs.get(role.limb, ""), role.kind), -1)
    for item in joint_map:
        tgt_name, sep, src_name = str(item).partition(":")
        tgt_name, src_name = tgt_name.strip(), src_name.strip()
        if not sep:
            raise ValueError(f"transfer.joint_map entry {item!r} is not '<target joint>:<source joint>'")
        if tgt_name not in target_env.joint_names:
            raise ValueError(f"transfer.joint_map: target joint {tgt_name!r} does not exist"
                             f"{_nearest(tgt_name, target_env.joint_names)} (target joints: "
                             f"{', '.join(target_env.joint_names)})")
        j = target_env.joint_names.index(tgt_name)
        if src_name.lower() == "none":
            src[j] = -1
            continue
        flip = src_name.startswith("-")
        src_name = src_name.lstrip("-")
        if src_name not in source_env.joint_names:
            raise ValueError(f"transfer.joint_map: source joint {src_name!r} does not exist"
                             f"{_nearest(src_name, source_env.joint_names)} (source joints: "
                             f"{', '.join(source_env.joint_names)})")
        src[j] = source_env.joint_names.index(src_name)
        extra_sign[j] = -1.0 if flip else 1.0
    signs = (lambda e: e.joint_flexion_signs) if knee == "flexion" else (lambda e: e.joint_signs)
    sign = np.where(src >= 0, signs(target_env) * signs(source_env)[np.maximum(src, 0)], 1.0)
    return src, sign * extra_sign, limbs


def _entry_key(entry: semantics.ObsEntry, joints: np.ndarray | None, limbs: dict | None):
    """The source-side key of an entry (through the joint and limb maps when given)."""
    index = entry.index
    if entry.quantity in semantics.JOINT_QUANTITIES and joints is not None:
        index = int(joints[int(index)])
        if index < 0:
            return None
    elif entry.quantity in semantics.LIMB_QUANTITIES and limbs is not None:
        index = limbs.get(str(index))
        if index is None:
            return None
    return entry.quantity, index, entry.frame


def build_map(source_env, target_env, joint_map: tuple[str, ...] = (), unmapped_blocks: tuple[str, ...] = (),
              knee: str = "axis") -> TransferMap:
    """The semantic correspondence of two envs (see the module docstring). Refusals name the
    joint or block that does not exist. ``knee``: how knees are signed (``joint_correspondence``)."""
    joint_src, joint_sign, limbs = joint_correspondence(source_env, target_env, joint_map, knee)
    scale_ratio = source_env.config.action_scale / target_env.config.action_scale
    joint_factor = np.where(joint_src >= 0, joint_sign * scale_ratio, 1.0)
    src_blocks, tgt_blocks = source_env.observation_blocks(), target_env.observation_blocks()
    block_names = sorted({b.name for blocks in tgt_blocks.values() for b in blocks})
    for name in unmapped_blocks:
        if name not in block_names:
            raise ValueError(f"transfer.unmapped_blocks: {name!r} is not a block of the target's "
                             f"observations{_nearest(name, block_names)} (blocks: {', '.join(block_names)})")
    obs = {}
    for key, blocks in tgt_blocks.items():
        source_entries = semantics.flatten(src_blocks[key])
        lookup = {_entry_key(e, None, None): (i, e) for i, e in enumerate(source_entries)}
        index, factor = [], []
        for b in blocks:
            skip = b.name in unmapped_blocks
            for e in b.entries:
                k = None if skip else _entry_key(e, joint_src, limbs)
                hit = lookup.get(k) if k is not None else None
                if hit is None:
                    index.append(-1)
                    factor.append(1.0)
                    continue
                i, se = hit
                f = e.scale / se.scale
                if e.quantity in semantics.JOINT_QUANTITIES:
                    f *= joint_sign[int(e.index)]
                index.append(i)
                factor.append(f)
        index, factor = np.asarray(index), np.asarray(factor)
        readers = np.bincount(index[index >= 0], minlength=len(source_entries))
        weight = np.where(index >= 0, np.sign(factor) / np.maximum(readers[np.maximum(index, 0)], 1), 0.0)
        obs[key] = EntryMap(index, factor, weight)
    pairs = tuple(
        (name, source_env.joint_names[s] if s >= 0 else "", float(f))
        for name, s, f in zip(target_env.joint_names, joint_src, joint_factor)
    )
    return TransferMap(obs, joint_src, joint_factor, pairs, limbs)


def _map_input_layer(src_w: jax.Array, m: EntryMap) -> jax.Array:
    rows = src_w[np.maximum(m.source_index, 0)]
    return jnp.where((m.source_index >= 0)[:, None], rows * m.weight[:, None].astype(src_w.dtype), 0.0)


def _map_mlp(src: Params, fresh: Params, m: EntryMap, output=None) -> Params:
    out = {name: dict(layer) for name, layer in src.items()}
    out["layer_0"] = {"w": _map_input_layer(src["layer_0"]["w"], m), "b": src["layer_0"]["b"]}
    if output is not None:
        last = f"layer_{len(src) - 1}"
        out[last] = output(src[last], fresh[last])
    return out


def apply(tmap: TransferMap, source_params: Params, source_normalizer: dict, target_params: Params,
          target_normalizer: dict, noise_std: float = 0.0, critic: bool = True,
          output: bool = True, input_layer: bool = True) -> tuple[Params, dict]:
    """The semantic transfer: the target's initial (params, normaliser) from the source's.
    ``target_params``/``target_normalizer`` are the fresh ones (unmapped output columns start
    from them). ``noise_std`` > 0 starts every joint's policy std there instead of carrying the
    source's. ``critic=False`` keeps the fresh critic (mode ``semantic_actor``); ``output=False``
    also keeps the actor's fresh output layer and log-std (mode ``semantic_input``);
    ``input_layer=False`` keeps the actor's fresh input layer and the fresh normaliser (with
    ``critic=False``: mode ``semantic_output``). Otherwise the normaliser is mapped (its
    statistics describe the target's observations, not a learned value). Traceable; the maps
    are static."""
    has = tmap.joint_source >= 0
    idx = np.maximum(tmap.joint_source, 0)
    f = tmap.joint_factor.astype(np.float32)

    def actor_output(s, fresh):
        w = jnp.where(has[None, :], s["w"][:, idx] * f[None, :], fresh["w"] * UNMAPPED_OUTPUT_SCALE)
        b = jnp.where(has, s["b"][idx] * f, 0.0)
        return {"w": w, "b": b}

    actor = _map_mlp(source_params["actor"], target_params["actor"], tmap.obs["state"], actor_output)
    critic_params = (_map_mlp(source_params["critic"], target_params["critic"], tmap.obs["privileged_state"])
                     if critic else target_params["critic"])
    if noise_std > 0:
        log_std = jnp.full_like(target_params["log_std"], np.log(noise_std))
    elif has.any():
        mapped_log_std = source_params["log_std"][idx] + np.log(np.abs(f))
        fill = jnp.sum(jnp.where(has, mapped_log_std, 0.0)) / has.sum()
        log_std = jnp.where(has, mapped_log_std, fill)
    else:
        log_std = target_params["log_std"]
    mapped = {"actor": actor, "log_std": log_std.astype(target_params["log_std"].dtype), "critic": critic_params}
    params = keep_fresh(mapped, target_params, fresh_critic=not critic, fresh_output=not output,
                        noise_std=noise_std, fresh_input=not input_layer)
    if not input_layer:
        return params, target_normalizer

    normalizer = {}
    for key, m in tmap.obs.items():
        s, t = source_normalizer[key], target_normalizer[key]
        hit = m.source_index >= 0
        i = np.maximum(m.source_index, 0)
        fac = m.factor.astype(np.float32)
        count = s.count
        mean = jnp.where(hit, s.mean[i] * fac, 0.0)
        m2 = jnp.where(hit, s.m2[i] * fac**2, count)  # unmatched: variance 1
        normalizer[key] = normalization.RunningStats(mean=mean.astype(t.mean.dtype), m2=m2.astype(t.m2.dtype),
                                                     count=jnp.asarray(count, t.count.dtype))
    return params, normalizer


FRESH_PARTS: dict[str, frozenset[str]] = {
    "semantic": frozenset(),
    "semantic_actor": frozenset({"critic"}),
    "semantic_input": frozenset({"critic", "output"}),
    "semantic_output": frozenset({"critic", "input"}),
}
"""Per semantic transfer mode (``freeze.TRANSFER_MODES``), the parts that start fresh instead of
mapped: ``critic``; ``output`` (the actor's output layer and log-std); ``input`` (the actor's
input layer and the normaliser). The one table ``apply``'s callers (the program, the transfer
tool) read their switches from."""


def fresh_switches(mode: str) -> dict[str, bool]:
    """``apply``'s keyword switches for semantic mode ``mode`` (``FRESH_PARTS``)."""
    parts = FRESH_PARTS[mode]
    return {"critic": "critic" not in parts, "output": "output" not in parts, "input_layer": "input" not in parts}


def keep_fresh(mapped: Params, fresh: Params, fresh_critic: bool | jax.Array, fresh_output: bool | jax.Array,
               noise_std: float = 0.0, fresh_input: bool | jax.Array = False) -> Params:
    """``mapped`` (``apply``'s params) with parts put back to ``fresh``'s: the critic where
    ``fresh_critic``; the actor's output layer and log-std where ``fresh_output`` (the log-std
    at ``noise_std`` when that is > 0); the actor's input layer where ``fresh_input`` (the
    normaliser is the caller's to pick). The switches may be traced booleans (the program picks
    per variant); a fresh output layer takes the plain init, not ``UNMAPPED_OUTPUT_SCALE``'s
    share of it, as the paper's transfer does."""
    where = lambda c, a, b: jax.tree.map(lambda x, y: jnp.where(c, x, y), a, b)  # noqa: E731
    last = f"layer_{len(fresh['actor']) - 1}"
    fresh_log_std = (jnp.full_like(fresh["log_std"], np.log(noise_std)) if noise_std > 0 else fresh["log_std"])
    actor = {**mapped["actor"], last: where(fresh_output, fresh["actor"][last], mapped["actor"][last]),
             "layer_0": where(fresh_input, fresh["actor"]["layer_0"], mapped["actor"]["layer_0"])}
    return {"actor": actor,
            "log_std": jnp.where(fresh_output, fresh_log_std, mapped["log_std"]).astype(fresh["log_std"].dtype),
            "critic": where(fresh_critic, fresh["critic"], mapped["critic"])}

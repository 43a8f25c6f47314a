"""The semantic transfer: declarations, the correspondence they imply, and the parameter surgery.

Hand-computed indices below follow the layouts in envs/quadruped.py (45-entry state: angular
velocity 0-2, projected gravity 3-5, joint positions 6-17, velocities 18-29, command 30-32, last
action 33-44; privileged adds linear velocity 45-47, height 48, contacts FL FR RL RR 49-52) and
envs/biped.py (47-entry frame: clock 0-1, command 2-4, joint positions 5-16, velocities 17-28,
last action 29-40, angular velocity 41-43, roll pitch yaw 44-46; the actor stacks 15 frames,
newest last; privileged: frame, linear velocity 47-49, height 50, stance 51-52, contacts 53-54,
joint error 55-66).
"""

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs import semantics
from ptrl_jax.core import normalization, semantic
from ptrl_jax.config import NetworkConfig
from ptrl_jax.core.networks import init_actor_critic, policy_apply, value_apply
from ptrl_jax.core.train import normalize_obs

XBOT_NEWEST = 14 * 47  # first entry of the newest of XBot-L's 15 stacked frames


@pytest.fixture(scope="module")
def robots():
    return {r: envs.make(r) for r in ("go2", "a1", "xbot_l", "tron1", "cassie", "mit_humanoid")}


def random_agent(key, env, network=NetworkConfig(actor_hidden=(16, 8, 4), critic_hidden=(16, 8, 4))):
    obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
    sizes = {k: int(v.shape[-1]) for k, v in obs.items()}
    k1, k2, k3 = jax.random.split(key, 3)
    params = init_actor_critic(k1, network, sizes["state"], sizes["privileged_state"], env.action_size)
    params["log_std"] = jax.random.normal(k3, params["log_std"].shape) * 0.3
    norm = {}
    for i, (k, n) in enumerate(sizes.items()):
        ka, kb = jax.random.split(jax.random.fold_in(k2, i))
        norm[k] = normalization.RunningStats(jax.random.normal(ka, (n,)), jnp.exp(jax.random.normal(kb, (n,))) * 100.0,
                                             jnp.float32(100.0))
    fresh_norm = {k: normalization.init(n) for k, n in sizes.items()}
    return params, norm, fresh_norm, network


class TestDeclarations:
    @pytest.mark.parametrize("robot", envs.robot_names())
    def test_blocks_cover_every_observation_entry(self, robot):
        env = envs.make(robot)
        obs = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).obs
        blocks = env.observation_blocks()
        assert set(blocks) == set(obs)
        for key, b in blocks.items():
            assert len(semantics.flatten(b)) == obs[key].shape[-1], (robot, key)
        assert len(env.joint_roles) == env.num_joints and env.joint_signs.shape == (env.num_joints,)

    def test_axis_signs_follow_the_model(self, robots):
        # XBot-L's left knee turns about -y, its left hip pitch about +y; Go2's are all +y.
        x = robots["xbot_l"]
        assert x.joint_signs[x.joint_names.index("left_knee_joint")] == -1.0
        assert x.joint_signs[x.joint_names.index("left_leg_pitch_joint")] == 1.0
        assert x.joint_signs[x.joint_names.index("right_leg_pitch_joint")] == -1.0
        assert (robots["go2"].joint_signs == 1.0).all()

    def test_a_bad_role_names_the_joint_and_the_nearest_kind(self):
        cfg = dataclasses.replace(envs.default_config("go2"),
                                  joint_roles=("FL:hip_rol",) + envs.default_config("go2").joint_roles[1:])
        with pytest.raises(ValueError, match="'FL_hip_joint' has role 'FL:hip_rol'.*did you mean 'hip_roll'"):
            envs.make("go2", cfg)

    def test_a_role_against_the_axis_is_refused(self):
        roles = list(envs.default_config("go2").joint_roles)
        roles[0] = "FL:hip_pitch"  # the abduction joint turns about x
        with pytest.raises(ValueError, match="'FL_hip_joint' is declared FL:hip_pitch"):
            envs.make("go2", dataclasses.replace(envs.default_config("go2"), joint_roles=tuple(roles)))


def same(a, b) -> bool:
    """Every leaf of two pytrees bitwise equal."""
    return all(jax.tree.leaves(jax.tree.map(np.array_equal, a, b)))


class TestARobotOntoItselfIsTheIdentity:
    """The joystick presets' second stage (`<biped>_joystick`) maps a robot onto itself."""

    @pytest.mark.parametrize("turning", [False, True], ids=["default_observation", "turning_observation"])
    @pytest.mark.parametrize("robot", ["tron1", "xbot_l", "mit_humanoid", "cassie"])
    def test_a_robot_onto_itself_carries_every_leaf_bitwise(self, robots, robot, turning):
        """On the observation the presets train (``observe_heading=false``, ``euler_order=zyx``)
        as on the default one; Cassie's passive tarsus and toe joints included."""
        env = robots[robot]
        if turning:
            env = envs.make(robot, dataclasses.replace(envs.default_config(robot), observe_heading=False,
                                                       euler_order="zyx"))
        src, src_norm, fresh_norm, _ = random_agent(jax.random.PRNGKey(0), env)
        fresh, _, _, _ = random_agent(jax.random.PRNGKey(1), env)
        params, norm = semantic.apply(semantic.build_map(env, env), src, src_norm, fresh, fresh_norm)
        assert jax.tree.structure(params) == jax.tree.structure(src)
        assert same(params, src) and same(norm, src_norm)


@pytest.fixture(scope="module")
def go2_a1(robots):
    """A random Go2 agent, a fresh A1 one, their map and the whole semantic transfer."""
    src, src_norm, fresh_norm, _ = random_agent(jax.random.PRNGKey(0), robots["go2"])
    fresh, _, _, _ = random_agent(jax.random.PRNGKey(1), robots["a1"])
    m = semantic.build_map(robots["go2"], robots["a1"])
    whole, whole_norm = semantic.apply(m, src, src_norm, fresh, fresh_norm)
    return SimpleNamespace(src=src, src_norm=src_norm, fresh=fresh, fresh_norm=fresh_norm, map=m,
                           whole=whole, whole_norm=whole_norm)


class TestGo2ToA1IsTheIdentity:
    @pytest.mark.parametrize("source, target", [("go2", "a1"), ("a1", "go2")])  # a1_to_go2 runs the reverse
    def test_the_map(self, robots, source, target):
        m = semantic.build_map(robots[source], robots[target])
        assert np.array_equal(m.joint_source, np.arange(12)) and (m.joint_factor == 1.0).all()
        for key, e in m.obs.items():
            assert np.array_equal(e.source_index, np.arange(e.source_index.size)), key
            assert (e.factor == 1.0).all() and (e.weight == 1.0).all(), key

    def test_actor_and_critic_outputs_are_bitwise_the_sources(self, robots):
        src, src_norm, fresh_norm, net = random_agent(jax.random.PRNGKey(0), robots["go2"])
        fresh, _, _, _ = random_agent(jax.random.PRNGKey(1), robots["a1"])
        m = semantic.build_map(robots["go2"], robots["a1"])
        params, norm = semantic.apply(m, src, src_norm, fresh, fresh_norm)
        obs = {"state": jax.random.normal(jax.random.PRNGKey(2), (5, 45)),
               "privileged_state": jax.random.normal(jax.random.PRNGKey(3), (5, 53))}
        a = policy_apply(src, normalize_obs(src_norm, obs, True), net)
        b = policy_apply(params, normalize_obs(norm, obs, True), net)
        assert np.array_equal(a.mean, b.mean) and np.array_equal(a.std, b.std)
        assert np.array_equal(value_apply(src, normalize_obs(src_norm, obs, True), net),
                              value_apply(params, normalize_obs(norm, obs, True), net))

    def test_noise_std_replaces_the_carried_std_and_nothing_else(self, robots):
        src, src_norm, fresh_norm, _ = random_agent(jax.random.PRNGKey(0), robots["go2"])
        fresh, _, _, _ = random_agent(jax.random.PRNGKey(1), robots["a1"])
        m = semantic.build_map(robots["go2"], robots["a1"])
        carried, _ = semantic.apply(m, src, src_norm, fresh, fresh_norm)
        reset, _ = semantic.apply(m, src, src_norm, fresh, fresh_norm, noise_std=0.5)
        np.testing.assert_allclose(np.exp(np.asarray(reset["log_std"])), 0.5, rtol=1e-6)
        assert np.array_equal(carried["log_std"], src["log_std"])
        same = jax.tree.map(np.array_equal, {k: carried[k] for k in ("actor", "critic")},
                            {k: reset[k] for k in ("actor", "critic")})
        assert all(jax.tree.leaves(same))

    def test_semantic_actor_keeps_the_fresh_critic_and_maps_the_rest(self, go2_a1):
        src, src_norm, fresh, fresh_norm, m = go2_a1.src, go2_a1.src_norm, go2_a1.fresh, go2_a1.fresh_norm, go2_a1.map
        whole, whole_norm = go2_a1.whole, go2_a1.whole_norm
        actor, actor_norm = semantic.apply(m, src, src_norm, fresh, fresh_norm, critic=False)
        assert same(actor["critic"], fresh["critic"]) and not same(actor["critic"], whole["critic"])
        assert same(actor["actor"], whole["actor"]) and same(actor["log_std"], whole["log_std"])
        assert same(actor_norm, whole_norm)

    def test_semantic_input_maps_only_what_the_actor_reads(self, go2_a1):
        """``output=False`` (mode semantic_input): the input layer, hidden layers and normaliser
        are the whole map's; the output layer, log-std and critic are the fresh network's (the
        output layer at its plain init, not the unmapped columns' small share of it)."""
        src, src_norm, fresh, fresh_norm, m = go2_a1.src, go2_a1.src_norm, go2_a1.fresh, go2_a1.fresh_norm, go2_a1.map
        whole, whole_norm = go2_a1.whole, go2_a1.whole_norm
        inp, inp_norm = semantic.apply(m, src, src_norm, fresh, fresh_norm, critic=False, output=False)
        last = f"layer_{len(fresh['actor']) - 1}"
        for layer in fresh["actor"]:
            assert same(inp["actor"][layer], (fresh if layer == last else whole)["actor"][layer]), layer
        assert not same(whole["actor"][last], fresh["actor"][last])
        assert same(inp["log_std"], fresh["log_std"]) and not same(whole["log_std"], fresh["log_std"])
        assert same(inp["critic"], fresh["critic"]) and same(inp_norm, whole_norm)
        restd, _ = semantic.apply(m, src, src_norm, fresh, fresh_norm, noise_std=0.3, critic=False, output=False)
        np.testing.assert_allclose(np.exp(np.asarray(restd["log_std"])), 0.3, rtol=1e-6)
        assert same(restd["actor"], inp["actor"])

    def test_semantic_output_maps_only_what_the_actor_writes(self, go2_a1):
        """``critic=False, input_layer=False`` (mode semantic_output): the output layer, log-std
        and hidden layers are the whole map's; the input layer, normaliser and critic are the
        fresh network's."""
        src, src_norm, fresh, fresh_norm, m = go2_a1.src, go2_a1.src_norm, go2_a1.fresh, go2_a1.fresh_norm, go2_a1.map
        whole, whole_norm = go2_a1.whole, go2_a1.whole_norm
        out, out_norm = semantic.apply(m, src, src_norm, fresh, fresh_norm, critic=False, input_layer=False)
        for layer in fresh["actor"]:
            assert same(out["actor"][layer], (fresh if layer == "layer_0" else whole)["actor"][layer]), layer
        assert not same(whole["actor"]["layer_0"], fresh["actor"]["layer_0"])
        assert same(out["log_std"], whole["log_std"]) and same(out["critic"], fresh["critic"])
        assert same(out_norm, fresh_norm) and not same(whole_norm, fresh_norm)

    def test_keep_fresh_under_jit_picks_per_switch_and_keeps_the_fresh_std_at_zero_noise(self, go2_a1):
        """The program's path: ``keep_fresh`` with traced switches, as ``jnp.where`` picks per
        variant. With ``noise_std=0`` a fresh output keeps the fresh network's own log-std."""
        whole = go2_a1.whole
        fresh = {**go2_a1.fresh, "log_std": go2_a1.fresh["log_std"] + 0.25}  # distinct from the source's
        pick = jax.jit(lambda c, o, i: semantic.keep_fresh(whole, fresh, c, o, noise_std=0.0, fresh_input=i))
        last = f"layer_{len(fresh['actor']) - 1}"
        for c, o, i in np.ndindex(2, 2, 2):
            got = pick(jnp.asarray(bool(c)), jnp.asarray(bool(o)), jnp.asarray(bool(i)))
            assert same(got["critic"], (fresh if c else whole)["critic"]), (c, o, i)
            assert same(got["actor"][last], (fresh if o else whole)["actor"][last]), (c, o, i)
            assert same(got["log_std"], (fresh if o else whole)["log_std"]), (c, o, i)
            assert same(got["actor"]["layer_0"], (fresh if i else whole)["actor"]["layer_0"]), (c, o, i)
            assert same(got["actor"]["layer_1"], whole["actor"]["layer_1"]), (c, o, i)
        assert not same(whole["log_std"], fresh["log_std"])

    def test_a_negative_noise_std_is_refused(self):
        from ptrl_jax.config import TransferConfig

        with pytest.raises(ValueError, match="transfer.noise_std must be >= 0"):
            TransferConfig(noise_std=-0.1)


class TestGo2ToXBotL:
    @pytest.fixture(scope="class")
    def transferred(self, robots):
        src, src_norm, _, net = random_agent(jax.random.PRNGKey(0), robots["go2"])
        fresh, _, fresh_norm, _ = random_agent(jax.random.PRNGKey(1), robots["xbot_l"])
        m = semantic.build_map(robots["go2"], robots["xbot_l"])
        params, norm = semantic.apply(m, src, src_norm, fresh, fresh_norm)
        return src, src_norm, fresh, params, norm

    def test_input_rows_land_in_the_right_columns(self, transferred):
        src, _, _, params, _ = transferred
        w_s, w_t = np.asarray(src["actor"]["layer_0"]["w"]), np.asarray(params["actor"]["layer_0"]["w"])
        hand = {  # XBot-L newest-frame entry -> (Go2 entry, sign)
            2: (30, 1), 3: (31, 1), 4: (32, 1),       # command vx, vy, yaw (scales absorbed by the stats)
            5 + 0: (6 + 6, 1),                        # left hip roll <- RL hip abduction
            5 + 2: (6 + 7, 1),                        # left hip pitch <- RL thigh
            5 + 3: (6 + 8, -1),                       # left knee (axis -y) <- RL calf (axis +y)
            5 + 8: (6 + 10, -1),                      # right hip pitch (axis -y) <- RR thigh
            17 + 3: (18 + 8, -1),                     # left knee velocity
            29 + 9: (33 + 11, 1),                     # right knee last action (right knee axis +y)
            41: (0, 1), 42: (1, 1), 43: (2, 1),       # angular velocity
            44: (4, -1), 45: (3, 1),                  # roll <- -gravity y, pitch <- gravity x
        }
        for t, (s, sign) in hand.items():
            assert np.array_equal(w_t[XBOT_NEWEST + t], sign * w_s[s]), t
        unmatched = [0, 1, 5 + 1, 5 + 4, 5 + 5, 46]  # clock, hip yaw, ankles, heading
        assert not w_t[[XBOT_NEWEST + u for u in unmatched]].any()
        assert not w_t[:XBOT_NEWEST].any()  # older frames start at zero
        assert np.array_equal(params["actor"]["layer_0"]["b"], src["actor"]["layer_0"]["b"])
        assert np.array_equal(params["actor"]["layer_1"]["w"], src["actor"]["layer_1"]["w"])

    def test_normaliser_statistics_are_converted(self, transferred):
        _, src_norm, _, _, norm = transferred
        s, t = src_norm["state"], norm["state"]
        # command yaw: Go2 observes 0.25 x rate, XBot-L 1 x rate
        assert np.isclose(t.mean[XBOT_NEWEST + 4], 4.0 * s.mean[32]) and np.isclose(t.m2[XBOT_NEWEST + 4], 16.0 * s.m2[32])
        assert np.isclose(t.mean[XBOT_NEWEST + 5 + 3], -s.mean[14])  # knee sign
        assert float(t.mean[0]) == 0.0 and float(t.m2[0]) == float(s.count)  # unmatched: mean 0, variance 1
        assert float(t.count) == float(s.count)

    def test_output_columns_and_log_std(self, transferred):
        src, _, fresh, params, _ = transferred
        w_s, w_t = np.asarray(src["actor"]["layer_3"]["w"]), np.asarray(params["actor"]["layer_3"]["w"])
        assert np.array_equal(w_t[:, 3], -w_s[:, 8])  # left knee <- -RL calf
        assert np.array_equal(w_t[:, 2], w_s[:, 7])
        assert np.allclose(w_t[:, 1], semantic.UNMAPPED_OUTPUT_SCALE * np.asarray(fresh["actor"]["layer_3"]["w"][:, 1]))
        assert params["actor"]["layer_3"]["b"][1] == 0.0
        ls = np.asarray(params["log_std"])
        assert ls[3] == src["log_std"][8]
        mapped = [0, 2, 3, 6, 8, 9]
        assert np.isclose(ls[1], ls[mapped].mean())

    def test_critic_contacts_come_from_the_hind_feet(self, transferred):
        src, _, _, params, _ = transferred
        w_s, w_t = np.asarray(src["critic"]["layer_0"]["w"]), np.asarray(params["critic"]["layer_0"]["w"])
        assert np.array_equal(w_t[53], w_s[51]) and np.array_equal(w_t[54], w_s[52])
        assert np.array_equal(w_t[47], w_s[45])  # linear velocity x
        assert not w_t[50].any()  # base height compares within a family only
        assert not w_t[[51, 52]].any() and not w_t[55:].any()  # stance and gait error: biped only
        assert np.array_equal(params["critic"]["layer_3"]["w"], src["critic"]["layer_3"]["w"])


class TestSharedInputsAreSplit:
    def test_two_quadruped_legs_share_one_biped_leg(self, robots):
        m = semantic.build_map(robots["xbot_l"], robots["go2"])
        e = m.obs["state"]
        fl_thigh, rl_thigh = 6 + 1, 6 + 7
        assert e.source_index[fl_thigh] == e.source_index[rl_thigh] == XBOT_NEWEST + 5 + 2
        assert e.weight[fl_thigh] == e.weight[rl_thigh] == 0.5
        assert m.joint_source[1] == m.joint_source[7] == 2


class TestOverridesAndRefusals:
    def test_a_joint_map_overrides_a_pair_and_flips_a_sign(self, robots):
        m = semantic.build_map(robots["go2"], robots["xbot_l"],
                               joint_map=("left_knee_joint:-FL_calf_joint", "left_leg_roll_joint:none"))
        assert m.joint_source[3] == 2 and m.joint_factor[3] == 1.0  # -1 (axes) x -1 (flip)
        assert m.joint_source[0] == -1

    def test_unknown_joints_and_blocks_are_named(self, robots):
        with pytest.raises(ValueError, match="target joint 'left_kne_joint' does not exist; did you mean 'left_knee_joint'"):
            semantic.build_map(robots["go2"], robots["xbot_l"], joint_map=("left_kne_joint:RL_calf_joint",))
        with pytest.raises(ValueError, match="source joint 'RL_calve_joint' does not exist; did you mean 'RL_calf_joint'"):
            semantic.build_map(robots["go2"], robots["xbot_l"], joint_map=("left_knee_joint:RL_calve_joint",))
        with pytest.raises(ValueError, match="'foot_contacts' is not a block.*did you mean 'foot_contact'"):
            semantic.build_map(robots["go2"], robots["xbot_l"], unmapped_blocks=("foot_contacts",))

    def test_unmapped_blocks_start_at_zero(self, robots):
        m = semantic.build_map(robots["go2"], robots["a1"], unmapped_blocks=("foot_contact",))
        assert (m.obs["privileged_state"].source_index[49:53] == -1).all()
        assert (m.obs["state"].source_index >= 0).all()

    def test_a_robot_without_roles_is_refused(self, robots):
        bare = envs.make("a1", dataclasses.replace(envs.default_config("a1"), joint_roles=()))
        with pytest.raises(ValueError, match="declares no joint_roles"):
            semantic.build_map(robots["go2"], bare)


class TestKneeConvention:
    """transfer.knee=flexion signs knees by the way they bend: Go2's calves bend backwards (home
    -1.8 rad), ANYmal's front knees too (-0.8) but its hind knees forwards (+0.8); XBot-L's knees
    are straight at home, so their flexion is the reference gait's swing sign."""

    def test_flexion_signs_read_the_home_pose(self, robots):
        go2, anymal = robots["go2"], envs.make("anymal_c")
        knees = [i for i, r in enumerate(go2.joint_roles) if r.kind == "knee"]
        assert knees == [2, 5, 8, 11]
        assert (go2.joint_flexion_signs[knees] == -1.0).all()
        assert anymal.joint_flexion_signs[knees].tolist() == [-1.0, -1.0, 1.0, 1.0]
        others = [i for i in range(12) if i not in knees]
        assert np.array_equal(anymal.joint_flexion_signs[others], anymal.joint_signs[others])

    def test_a_straight_knee_takes_the_declared_swing_sign(self, robots):
        x = robots["xbot_l"]
        left, right = x.joint_names.index("left_knee_joint"), x.joint_names.index("right_knee_joint")
        # XBot-L's reference gait lifts the left foot with a negative knee angle, the right with a positive one.
        assert x.joint_flexion_signs[left] == -1.0 and x.joint_flexion_signs[right] == 1.0

    def test_hind_knees_of_anymal_flip_under_flexion(self, robots):
        anymal = envs.make("anymal_c")
        axis = semantic.build_map(robots["go2"], anymal, knee="axis")
        flex = semantic.build_map(robots["go2"], anymal, knee="flexion")
        expected = np.full(12, 0.5)  # action scales 0.25 / 0.5
        np.testing.assert_array_equal(axis.joint_factor, expected)
        expected[[8, 11]] = -0.5  # RL_calf, RR_calf
        np.testing.assert_array_equal(flex.joint_factor, expected)
        # The hind knees' position, velocity and last-action inputs flip with them (state entries
        # 6 + 8, 18 + 8, 33 + 8); the front knee's do not.
        for entry in (14, 26, 41, 17, 29, 44):
            assert flex.obs["state"].weight[entry] == -1.0 and axis.obs["state"].weight[entry] == 1.0
        for entry in (8, 20, 35):
            assert flex.obs["state"].weight[entry] == 1.0

    def test_the_conventions_agree_where_knees_bend_the_same_way(self, robots):
        pairs = [("go2", "a1"), ("xbot_l", "cassie"), ("xbot_l", "mit_humanoid"), ("cassie", "xbot_l")]
        for s, t in pairs:
            src, tgt = envs.make(s), envs.make(t)
            a, f = semantic.build_map(src, tgt, knee="axis"), semantic.build_map(src, tgt, knee="flexion")
            np.testing.assert_array_equal(a.joint_factor, f.joint_factor, err_msg=f"{s} -> {t}")

    def test_tron1_and_go2_knees_flex_against_xbot_l_axes(self, robots):
        # TRON1's and Go2's knees bend backwards, XBot-L's forwards: the axis map extends where the
        # source flexes, the flexion map flexes.
        for s, t in (("xbot_l", "tron1"), ("go2", "xbot_l")):
            src, tgt = robots[s], robots[t]
            a, f = semantic.build_map(src, tgt, knee="axis"), semantic.build_map(src, tgt, knee="flexion")
            knees = [j for j, r in enumerate(tgt.joint_roles) if r.kind == "knee"]
            assert (np.sign(a.joint_factor[knees]) == -np.sign(f.joint_factor[knees])).all(), (s, t)
            for j in knees:  # flexion of the target = flexion of the source times |factor|
                sj = f.joint_source[j]
                assert tgt.joint_flexion_signs[j] * f.joint_factor[j] * src.joint_flexion_signs[sj] > 0

    def test_a_straight_undeclared_knee_is_refused_naming_it(self):
        from envs.base import LeggedEnv

        x = envs.make("xbot_l")
        with pytest.raises(ValueError, match="knee 'left_knee_joint' is straight at home"):
            semantics.knee_flexion_signs(x.mj_model, x.joint_roles, x.joint_signs, {})
        assert LeggedEnv.declared_flexion(x) == {}

    def test_a_declaration_against_the_bent_pose_is_refused(self):
        a = envs.make("anymal_c")
        with pytest.raises(ValueError, match="knee 'RL_calf_joint' is bent \\+0.80 rad at home"):
            semantics.knee_flexion_signs(a.mj_model, a.joint_roles, a.joint_signs, {8: -1.0})

    def test_an_unknown_convention_is_refused(self, robots):
        from ptrl_jax.config import TransferConfig

        with pytest.raises(ValueError, match="transfer.knee must be one of \\['axis', 'flexion'\\], got 'bent'"):
            TransferConfig(knee="bent")
        with pytest.raises(ValueError, match="transfer.knee must be one of"):
            semantic.build_map(robots["go2"], robots["a1"], knee="bent")


class TestVariantNames:
    def test_mode_suffixes(self):
        from ptrl_jax.core.freeze import variant, with_mode

        assert variant("L2@semantic").mode_index == 2 and variant("L2").mode_index == 1
        assert variant("L2@semantic_actor").mode_index == 3 and variant("L2@semantic_actor").frozen == ("L2",)
        assert variant("L2@semantic_input").mode_index == 4 and variant("L2@semantic_input").frozen == ("L2",)
        assert variant("L2@semantic_output").mode_index == 5 and variant("L2@semantic_output").frozen == ("L2",)
        assert variant("scratch").mode_index == 0
        assert with_mode("rho0.5", "semantic") == "rho0.5@semantic" and with_mode("scratch", "semantic") == "scratch"
        assert variant("L2@paper").name == "L2"
        with pytest.raises(ValueError, match="unknown transfer mode 'semantc'"):
            variant("L2@semantc")
        with pytest.raises(ValueError, match="'scratch' transfers nothing"):
            variant("scratch@semantic")

    def test_every_semantic_mode_says_what_starts_fresh(self):
        from ptrl_jax.core.freeze import TRANSFER_MODES

        assert set(semantic.FRESH_PARTS) == set(TRANSFER_MODES) - {"paper"}
        assert semantic.fresh_switches("semantic_output") == {"critic": False, "output": True, "input_layer": False}

    def test_transfer_semantic_names_the_variants(self):
        from ptrl_jax.io.overrides import load_experiment

        cfg = load_experiment("go2_to_xbot", ["scale=smoke", "transfer=semantic", "freeze_presets=[L2,none@paper,scratch]",
                                              "freeze_ratio=[0.5]"])
        assert cfg.variants == ("L2@semantic", "none", "scratch", "rho0.5@semantic")
        assert cfg.semantic and cfg.transfer.mode == "semantic"


@pytest.mark.xdist_group("smoke_go2_to_xbot")  # uses the smoke run of test_end_to_end
class TestTransferTool:
    def test_writes_a_checkpoint_that_a_run_accepts(self, smoke_run, tmp_path, capsys):
        from ptrl_jax import transfer
        from ptrl_jax.io import artifacts
        from ptrl_jax.io.overrides import load_experiment
        from ptrl_jax.core.program import make_program
        from ptrl_jax.io.checkpoints import load_init_target

        _, run_dir = smoke_run
        out = tmp_path / "xbot_init.npz"
        assert transfer.main([f"source={run_dir / 'source.npz'}", "target=xbot_l", "mode=semantic", f"out={out}"]) == 0
        ckpt = artifacts.load_checkpoint(out)
        assert ckpt["meta"]["robot"] == "xbot_l" and ckpt["meta"]["transfer"]["mode"] == "semantic"
        knee = next(j for j in ckpt["meta"]["transfer"]["joints"] if j["target"] == "left_knee_joint")
        assert knee == {"target": "left_knee_joint", "source": "RL_calf_joint", "factor": -1.0}
        src = artifacts.load_checkpoint(run_dir / "source.npz")["params"]
        assert np.array_equal(ckpt["params"]["critic"]["layer_2"]["w"], src["critic"]["layer_2"]["w"])

        cfg = load_experiment("go2_to_xbot", ["scale=smoke", f"init_checkpoint={out}", "freeze_presets=[L2,scratch]",
                                              "freeze_ratio=[]", "engine=mujoco"])  # no MJX trace: 20 s less
        assert not cfg.trains_source and cfg.source_iterations == 0
        program = make_program(cfg)
        start = load_init_target(cfg, program)
        state = jax.eval_shape(program.init, jax.random.PRNGKey(0), None, start)  # the run's own check
        assert state.init_target["params"]["actor"]["layer_0"]["w"].shape == (705, 512)
        first = program.start_weights(jax.random.PRNGKey(0), None, start)["xbot_l"]
        assert np.array_equal(first.params["actor"]["layer_0"]["w"][0, 0], ckpt["params"]["actor"]["layer_0"]["w"])
        assert not np.array_equal(first.params["actor"]["layer_0"]["w"][1, 0], ckpt["params"]["actor"]["layer_0"]["w"])

    def test_semantic_actor_variants_start_from_the_mapped_actor_and_a_fresh_critic(self, smoke_run, tmp_path):
        """In the program: L2@semantic_actor's actor and normaliser are L2@semantic's, its critic
        is the paper variant's (fresh from the same seed key), and the tool writes the same."""
        from ptrl_jax import transfer
        from ptrl_jax.io import artifacts
        from ptrl_jax.io.overrides import load_experiment
        from ptrl_jax.core.program import make_program
        from ptrl_jax.io.checkpoints import load_source_params

        _, run_dir = smoke_run
        src = run_dir / "source.npz"
        cfg = load_experiment("go2_to_a1", ["scale=smoke", f"source_checkpoint={src}", "engine=mujoco",
                                            "freeze_presets=[L2@semantic,L2@semantic_actor,L2,L2@semantic_input,"
                                            "L2@semantic_output]"])
        program = make_program(cfg)
        first = program.start_weights(jax.random.PRNGKey(0), load_source_params(cfg, program))
        params, norm = first["a1"].params, first["a1"].normalizer
        pick = lambda tree, p: jax.tree.map(lambda x: np.asarray(x[p]), tree)  # noqa: E731
        sem, actor, paper, inp, outp = (pick(params, p) for p in range(5))
        assert same(actor["actor"], sem["actor"]) and same(actor["log_std"], sem["log_std"])
        assert same(pick(norm, 1), pick(norm, 0)) and same(pick(norm, 3), pick(norm, 0))
        assert same(actor["critic"], paper["critic"]) and not same(actor["critic"], sem["critic"])
        # semantic_input: the mapped input layer, the source's hidden layers (as the paper's
        # transfer copies them), and the paper variant's fresh output layer, log-std and critic.
        last = f"layer_{len(paper['actor']) - 1}"
        assert same(inp["actor"]["layer_0"], sem["actor"]["layer_0"])
        assert not same(inp["actor"]["layer_0"], paper["actor"]["layer_0"])
        for layer in ("layer_1", "layer_2"):
            assert same(inp["actor"][layer], paper["actor"][layer]) and same(inp["actor"][layer], sem["actor"][layer])
        assert same(inp["actor"][last], paper["actor"][last]) and same(inp["critic"], paper["critic"])
        # semantic_output: the paper variant's fresh input layer, normaliser and critic, the
        # source's hidden layers, and the mapped output layer and log-std.
        assert same(outp["actor"]["layer_0"], paper["actor"]["layer_0"]) and same(pick(norm, 4), pick(norm, 2))
        assert not same(pick(norm, 4), pick(norm, 0))
        for layer in ("layer_1", "layer_2", last):
            assert same(outp["actor"][layer], sem["actor"][layer]), layer
        assert not same(outp["actor"][last], paper["actor"][last])
        assert same(outp["log_std"], sem["log_std"]) and same(outp["critic"], paper["critic"])
        assert cfg.transfer.noise_std == 0.5  # go2_to_a1 restarts every semantic std at 0.5
        np.testing.assert_allclose(np.exp(inp["log_std"]), 0.5, rtol=1e-6)
        source_critic = artifacts.load_checkpoint(src)["params"]["critic"]
        assert np.array_equal(sem["critic"]["layer_1"]["w"][0], source_critic["layer_1"]["w"])

        out = tmp_path / "a1_actor.npz"
        assert transfer.main([f"source={src}", "target=a1", "mode=semantic_actor", f"out={out}"]) == 0
        meta = artifacts.load_checkpoint(out)["meta"]["transfer"]
        assert meta["mode"] == "semantic_actor" and meta["critic"] == "fresh" and meta["output_layer"] == "mapped"
        assert transfer.main([f"source={src}", "target=a1", "mode=semantic_input", f"out={out}"]) == 0
        written = artifacts.load_checkpoint(out)
        assert written["meta"]["transfer"]["output_layer"] == "fresh" and written["meta"]["transfer"]["input_layer"] == "mapped"
        assert np.array_equal(written["params"]["actor"]["layer_0"]["w"], inp["actor"]["layer_0"]["w"][0])  # seed 0
        assert transfer.main([f"source={src}", "target=a1", "mode=semantic_output", f"out={out}"]) == 0
        written = artifacts.load_checkpoint(out)
        assert written["meta"]["transfer"]["input_layer"] == "fresh" and written["meta"]["transfer"]["output_layer"] == "mapped"
        assert np.array_equal(written["params"]["actor"]["layer_3"]["w"], outp["actor"]["layer_3"]["w"][0])  # seed 0

    def test_refusals_name_what_is_wrong(self, smoke_run, tmp_path, capsys):
        from ptrl_jax import transfer

        _, run_dir = smoke_run
        assert transfer.main([f"source={run_dir / 'source.npz'}", "target=xbot", f"out={tmp_path / 'x.npz'}"]) == 2
        assert "unknown robot 'xbot'" in capsys.readouterr().err
        assert transfer.main([f"source={run_dir / 'source.npz'}", "target=a1", "mode=clever", f"out={tmp_path / 'x.npz'}"]) == 2
        assert "mode='clever'" in capsys.readouterr().err
        assert transfer.main([f"source={run_dir / 'source.npz'}", "target=a1", f"out={tmp_path / 'x.npz'}",
                              "joint_map=[FL_hip_joint:FL_hipp_joint]"]) == 2
        assert "did you mean 'FL_hip_joint'" in capsys.readouterr().err
        assert not (tmp_path / "x.npz").exists()


@pytest.mark.slow  # compiles a whole target program (about a minute on 2 cores)
def test_initial_weights_are_bitwise_those_the_target_stage_starts_from(tmp_path):
    """``Program.start_weights`` (the zero-shot checks' weights, computed without env states)
    against the target states the program builds when its target stage starts: every variant,
    every seed, params and normaliser."""
    from ptrl_jax.io.overrides import load_experiment
    from ptrl_jax.core.program import make_program

    from ptrl_jax.io import artifacts
    from ptrl_jax.io.checkpoints import load_source_params

    params, norm, _, _ = random_agent(jax.random.PRNGKey(3), envs.make("go2"), NetworkConfig())
    src = tmp_path / "go2.npz"
    norm = {k: {"mean": np.asarray(v.mean), "m2": np.asarray(v.m2), "count": np.asarray(v.count)} for k, v in norm.items()}
    artifacts.save_checkpoint(src, params, norm, jax.tree.map(lambda p: np.zeros(p.shape, bool), params),
                              {"robot": "go2", "stage": "source"})
    cfg = load_experiment("go2_to_a1", ["scale=smoke", "engine=mujoco", "seeds=2", f"source_checkpoint={src}",
                                        "report.zero_shot_check=false",
                                        "freeze_presets=[L2,L2@semantic,L2@semantic_actor,L2@semantic_input,"
                                        "L2@semantic_output,scratch]"])
    program = make_program(cfg)
    source = load_source_params(cfg, program)
    key = jax.random.PRNGKey(7)
    started = jax.jit(program.advance)(jax.jit(program.init)(key, source), jnp.int32(0))
    assert bool(started.targets_started) and int(started.targets["a1"].iteration.max()) == 0
    weights = program.start_weights(key, source)["a1"]
    same = jax.tree.map(np.array_equal, (weights.params, weights.normalizer),
                        (started.targets["a1"].params, started.targets["a1"].normalizer))
    assert all(jax.tree.leaves(same))
    assert all(jax.tree.leaves(jax.tree.map(np.array_equal, program.initial_weights(started)["a1"], weights)))

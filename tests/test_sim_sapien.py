"""The SAPIEN backend against independent references: SAPIEN's own joint API, gravity, and physical
sense of contact forces. What every backend must do (FK against pytorch-kinematics, rest heights,
joint and wrist driving, object replacement, reset, determinism, argument and state errors) is in
test_sim_contract.py."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import partial
from itertools import combinations

import numpy as np
import pytest

from ges_core.errors import AssetError, ConfigError, SimulationError
from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.urdf import WRIST_JOINTS, neighbour_link_pairs
from ges_plugins.hands.shadow.hand import ShadowHand
from ges_plugins.sims.sapien.backend import SapienBackend
from ges_plugins.sims.sapien.bench import allegro_top_down
from ges_plugins.sims.sapien.loading import PAIR_BITS, exclusion_groups, pair_exclusion_bits

from helpers_sim import ALLEGRO_TIPS, UP, allegro_test_hand, box_asset, loaded_sim, open_q, run_python

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def hand():
    return allegro_test_hand()


make_sim = partial(loaded_sim, SapienBackend)
"""A SapienBackend with ``SceneConfig(**scene)``, the hand loaded if given."""


# -- joint order ---------------------------------------------------------------------------------
@pytest.mark.parametrize("floating", [True, False])
def test_joint_values_come_back_by_name_through_sapiens_own_api(hand, floating):
    """A distinct value per joint name, set by our teleport and read back by name by SAPIEN itself."""
    d = hand.description
    lim = d.limits_array
    target = lim[:, 0] + (np.arange(d.num_joints) + 1) / (d.num_joints + 1) * (lim[:, 1] - lim[:, 0])
    sim = make_sim(hand, floating=floating)
    sim.set_hand_state(target[None], UP[None])
    q, _ = sim.joint_state()
    np.testing.assert_allclose(q[0], target, atol=1e-6)  # float32 inside SAPIEN
    articulation = sim._envs[0].hand
    sapien_by_name = {j.name: v for j, v in zip(articulation.get_active_joints(), articulation.get_qpos(), strict=True)}
    np.testing.assert_allclose([sapien_by_name[n] for n in d.joint_names], q[0], atol=1e-6)
    assert [n for n in sapien_by_name if n in WRIST_JOINTS] == (list(WRIST_JOINTS) if floating else [])


def test_index_maps_are_inverse_permutations(hand):
    sim = make_sim(hand)
    assert np.array_equal(sim.idx_sim_to_hand[sim.idx_hand_to_sim], np.arange(hand.description.num_joints))
    sim_names = [j.name for j in sim._envs[0].hand.get_active_joints()][len(WRIST_JOINTS) :]
    assert [sim_names[i] for i in sim.idx_sim_to_hand] == list(hand.description.joint_names)
    assert sim_names != list(hand.description.joint_names)  # SAPIEN's order differs: the map matters


# -- objects on the table -----------------------------------------------------------------------
def test_zero_gravity_keeps_the_object_floating():
    sim = make_sim(gravity=0.0)
    sim.load_object(box_asset(), pose=UP)
    sim.step(60)
    np.testing.assert_allclose(sim.object_pose()[0], UP, atol=1e-6)


def test_convex_part_loads_from_file(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    path = tmp_path / "part.obj"
    trimesh.creation.box(extents=[0.06, 0.04, 0.05]).export(path)
    obj = ObjectAsset(object_id="t/convex", category="c", mesh_path=path, collision=(ConvexPart(path=path),))
    sim = make_sim()
    sim.load_object(obj)
    sim.step(60)
    assert abs(sim.object_pose()[0, 2] - 0.025) < 1e-3
    mass = sim._envs[0].obj_body.mass
    assert mass == pytest.approx(500.0 * 0.06 * 0.04 * 0.05, rel=1e-3)


def test_replacing_the_object_leaves_one_body_per_scene():
    """The engine-side half of the contract's object-replacement test: the old body is gone from PhysX."""
    sim = make_sim(num_envs=2)
    sim.load_object(box_asset(object_id="t/small"))
    sim.load_object(box_asset((0.05, 0.05, 0.05), object_id="t/big"), env_ids=[1])
    sim.step(60)
    for env, name in zip(sim._envs, ("t/small", "t/big"), strict=True):
        assert len(env.scene.physx_system.get_rigid_dynamic_components()) == 1
        assert {p.link_a for p in sim.contact_pairs(sim._envs.index(env))} == {name}


def test_contacts_read_right_after_replacing_the_object_are_empty_not_a_crash(hand):
    """PhysX still lists the removed body's contacts until the next step; touching them segfaulted."""
    sim = make_sim(hand)
    sim.set_hand_state(open_q(hand), UP[None])
    sim.load_object(box_asset(object_id="t/first"))
    sim.step(30)
    assert len(sim.contact_pairs(0)) > 0
    sim.load_object(box_asset((0.04, 0.04, 0.04), object_id="t/second"))
    assert np.all(sim.contact_forces(list(hand.description.tip_links), "any") == 0)
    assert sim.contact_pairs(0) == []
    sim.step(30)
    assert {p.link_a for p in sim.contact_pairs(0) if p.body_a == "object"} == {"t/second"}


def test_contact_pairs_report_the_weight_of_a_resting_box():
    sim = make_sim()
    box = box_asset()
    sim.load_object(box)
    sim.step(60)
    (pair,) = sim.contact_pairs(0)
    assert (pair.body_a, pair.link_a, pair.body_b) == ("object", "test/box", "table")
    assert pair.force == pytest.approx(box.mass * 9.81, rel=0.02)


# -- grasp contacts -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def grasp(hand):
    """A floating Allegro closed top-down on a 7 cm box (self-collision off so partners add up)."""
    obj, wrist, q = allegro_top_down(hand)
    sim = make_sim(hand, self_collision=False)
    sim.load_object(obj)
    sim.set_hand_state(open_q(hand), wrist[None])
    sim.set_wrist_targets(wrist[None])
    q0 = np.asarray(hand.description.open_pose)
    for i in range(1, 121):
        sim.set_joint_targets((q0 + min(1.0, i / 60) * (q - q0))[None])
        sim.step()
    forces = {p: sim.contact_forces(ALLEGRO_TIPS, p)[0] for p in ("object", "table", "any")}
    return sim, forces, sim.link_poses(ALLEGRO_TIPS)[0], sim.object_pose()[0]


def test_closing_hand_presses_fingertips_on_the_box(grasp):
    sim, forces, tips, box = grasp
    touching = np.linalg.norm(forces["object"], axis=1) > 0.5
    assert touching.sum() >= 2
    outward = np.einsum("ij,ij->i", forces["object"], tips[:, :3] - box[:3])
    assert np.all(outward[touching] > 0)  # the box pushes each fingertip away from its centre
    slow = {p.link_a for p in sim.contact_pairs(0) if p.body_b == "object" and p.force > 0}
    assert {ALLEGRO_TIPS[i] for i in np.flatnonzero(touching)} <= slow


def test_contact_partners_are_filtered(grasp):
    _, forces, _, _ = grasp
    np.testing.assert_allclose(forces["any"], forces["object"] + forces["table"], atol=1e-9)
    on_table = np.linalg.norm(forces["table"], axis=1) > 0.5
    on_box = np.linalg.norm(forces["object"], axis=1) > 0.5
    assert np.all(forces["table"][on_table, 2] > 0)  # the table pushes up
    assert on_table.any() and (on_box & ~on_table).any()  # the partners differ tip by tip


def test_repeated_links_get_the_same_force(grasp):
    sim, forces, _, _ = grasp
    twice = sim.contact_forces([ALLEGRO_TIPS[2], ALLEGRO_TIPS[2]], "object")[0]
    np.testing.assert_array_equal(twice, [forces["object"][2]] * 2)


# -- collisions inside the hand ------------------------------------------------------------------
def _parent_child_pairs(urdf_text: str) -> set[frozenset[str]]:
    root = ET.fromstring(urdf_text)
    return {frozenset((j.find("parent").get("link"), j.find("child").get("link"))) for j in root.findall("joint")}


@pytest.mark.parametrize("self_collision", [True, False])
def test_self_collision_setting(hand, self_collision):
    sim = make_sim(hand, floating=False, self_collision=self_collision)
    lim = hand.description.limits_array
    rng = np.random.default_rng(0)
    found = set()
    for q in rng.uniform(lim[:, 0], lim[:, 1], size=(20, len(lim))):
        sim.set_hand_state(q[None], UP[None])
        sim.step(1)
        found |= {frozenset((p.link_a, p.link_b)) for p in sim.contact_pairs(0) if p.body_a == p.body_b == "hand"}
    assert bool(found) == self_collision
    assert not found & _parent_child_pairs(hand.urdf_text())


def _filtered(groups_a: list[list[int]], groups_b: list[list[int]]) -> bool:
    """SAPIEN's PhysX filter (TypeAffinityIgnoreFilterShader): a shared group-2 bit and equal low 16 bits of group 3."""
    return any(a[2] & b[2] and (a[3] & 0xFFFF) == (b[3] & 0xFFFF) for a in groups_a for b in groups_b)


def _sapien_filtered_pairs(sim: SapienBackend) -> tuple[set[frozenset[str]], set[str]]:
    """Link pairs whose shapes SAPIEN's filter keeps apart, read back from the built shapes, and the solid links."""
    links = {link.name: link.get_collision_shapes() for link in sim._envs[0].hand.get_links()}
    groups = {name: [s.get_collision_groups() for s in shapes] for name, shapes in links.items() if shapes}
    return {frozenset((a, b)) for a, b in combinations(groups, 2) if _filtered(groups[a], groups[b])}, set(groups)


def test_shadow_pair_bits_filter_exactly_the_extra_neighbour_pairs():
    """Read back from the built shapes: with every pair colliding but the neighbours (``self_collision: all``), the
    pairs SAPIEN filters are the neighbour pairs that PhysX does not already skip as parent-child, and no others (the
    physics is tested in test_sims_cross)."""
    shadow = ShadowHand(self_collision="all")
    filtered, solid = _sapien_filtered_pairs(make_sim(shadow))
    expected = neighbour_link_pairs(shadow.urdf_text()) - _parent_child_pairs(shadow.urdf_text())
    assert filtered == {pair for pair in expected if pair <= solid}
    assert {frozenset(("palm", "thproximal")), frozenset(("thproximal", "thmiddle"))} <= filtered


def test_shadow_collides_in_sapien_exactly_the_pairs_mujoco_lists():
    """The default Shadow (``self_collision: mjcf_pairs``) leaves 170 pairs out, far more than SAPIEN's 29 bits could
    exclude one per pair: the pairs SAPIEN lets collide, read back from its shapes, are MuJoCo's own ``<contact>
    <pair>`` list of the compiled MJCF (parent-child pairs, which PhysX skips itself, aside)."""
    from ges_plugins.hands.shadow.assets import compile_model
    from ges_plugins.hands.shadow.convert import contact_pairs_from_mjmodel

    shadow = load_registry().build_hand("shadow")
    filtered, solid = _sapien_filtered_pairs(make_sim(shadow))
    colliding = (
        {frozenset(p) for p in combinations(sorted(solid), 2)} - filtered - _parent_child_pairs(shadow.urdf_text())
    )
    assert colliding == {frozenset(pair) for pair in contact_pairs_from_mjmodel(compile_model())}
    assert len(filtered) > PAIR_BITS


def test_self_collision_off_filters_every_hand_pair_and_not_the_table():
    """self_collision=False: every hand shape pair is filtered, the table still collides with the hand."""
    off = make_sim(load_registry().build_hand("shadow"), self_collision=False)
    groups = [s.get_collision_groups() for link in off._envs[0].hand.get_links() for s in link.get_collision_shapes()]
    assert all(_filtered([a], [b]) for a, b in combinations(groups, 2))
    table = off._envs[0].scene.entities[0].components[0].collision_shapes[0].get_collision_groups()
    assert not any(_filtered([table], [g]) for g in groups)


def test_too_many_excluded_pairs_is_an_asset_error():
    """30 links hanging from one zero-length hub all touch the base: 30 pairs, 29 bits."""
    box = '<collision><geometry><box size="0.01 0.01 0.01"/></geometry></collision>'
    leaves = "".join(
        f'<link name="leaf{i}">{box}</link><joint name="j{i}" type="revolute"><parent link="hub"/>'
        f'<child link="leaf{i}"/><origin xyz="0 0 0"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'
        for i in range(PAIR_BITS + 1)
    )
    text = (
        f'<robot name="star"><link name="base">{box}</link><link name="hub"/>'
        '<joint name="hub" type="fixed"><parent link="base"/><child link="hub"/><origin xyz="0 0 0.1"/></joint>'
        f"{leaves}</robot>"
    )
    with pytest.raises(AssetError, match=r"hand 'star': 30 link pairs \(joined through zero-length links.* 29 "):
        pair_exclusion_bits("star", text, neighbour_link_pairs(text))
    fewer = text.replace(f'<link name="leaf{PAIR_BITS}">{box}', f'<link name="leaf{PAIR_BITS}">')
    bits = pair_exclusion_bits("star", fewer, neighbour_link_pairs(fewer))
    assert bits["base"] == (1 << PAIR_BITS) - 1 and sorted(bits[f"leaf{i}"] for i in range(PAIR_BITS)) == [
        1 << i for i in range(PAIR_BITS)
    ]


@pytest.mark.parametrize("seed", range(6))
def test_exclusion_groups_share_a_group_exactly_for_the_pairs_allowed(seed):
    """Random link graphs: every pair that must be kept apart shares a group, no pair outside ``may`` does, and the
    same input gives the same groups."""
    rng = np.random.default_rng(seed)
    links = [f"l{i}" for i in range(int(rng.integers(4, 22)))]
    pairs = [frozenset(p) for p in combinations(links, 2)]
    chosen = rng.random(len(pairs))
    density = rng.uniform(0.1, 0.95)
    must = {p for p, c in zip(pairs, chosen, strict=True) if c < density}
    may = must | {p for p, c in zip(pairs, chosen, strict=True) if density <= c < density + 0.05}
    groups = exclusion_groups(must, may)
    shared = {frozenset((a, b)) for g in groups for a, b in combinations(g, 2)}
    assert must <= shared <= may
    assert groups == exclusion_groups(set(must), set(may))
    assert len(groups) <= max(len(must), 1)


def test_dense_exclusions_take_few_groups():
    """The complement of a sparse graph (a hand colliding only a few pairs) fits in a handful of groups, where one bit
    per pair would need one per excluded pair: 20 links, only a ring of 20 pairs colliding."""
    links = [f"l{i:02d}" for i in range(20)]
    ring = {frozenset((links[i], links[(i + 1) % 20])) for i in range(20)}
    must = {frozenset(p) for p in combinations(links, 2)} - ring
    groups = exclusion_groups(must, must)
    assert {frozenset((a, b)) for g in groups for a, b in combinations(g, 2)} == must
    assert len(groups) <= PAIR_BITS < len(must)


@pytest.mark.parametrize("hand_gravity", [True, False])
def test_hand_gravity_setting(hand, hand_gravity):
    sim = make_sim(hand, hand_gravity=hand_gravity)
    sim.set_hand_state(open_q(hand), UP[None])
    sim.step(120)
    sag = UP[2] - sim.wrist_pose()[0, 2]
    assert (1e-4 < sag < 2e-3) if hand_gravity else abs(sag) < 1e-5


# -- explosions ----------------------------------------------------------------------------------
def test_huge_targets_raise_exploding_in_the_right_env(hand):
    sim = make_sim(hand, num_envs=2)
    sim.set_hand_state(open_q(hand, 2), np.tile(UP, (2, 1)))
    wrist = np.tile(UP, (2, 1))
    wrist[1, 0] = 1e30  # a wrist target 1e30 m away: the PD force overflows any sane velocity
    sim.set_wrist_targets(wrist)
    with pytest.raises(SimulationError, match=r"sapien env 1: exploding hand joint '\w+' velocity \(\d"):
        sim.step(3)


def test_overflowing_targets_raise_non_finite(hand):
    sim = make_sim(hand)
    sim.set_hand_state(open_q(hand), UP[None])
    sim.set_joint_targets(np.full((1, hand.description.num_joints), 3e38))
    with pytest.raises(SimulationError, match=r"sapien env 0: non-finite hand joint .* velocity \(nan"):
        sim.step(5)


def test_object_explosion_is_reported():
    sim = make_sim(gravity=-1e6)
    sim.load_object(box_asset(), pose=UP)
    with pytest.raises(SimulationError, match=r"sapien env 0: exploding object velocity"):
        sim.step(1)


# -- asset and setting errors ----------------------------------------------------------------------
def test_bad_object_assets_are_rejected(tmp_path):
    sim = make_sim()
    mesh = box_asset().mesh_path

    def asset(*shapes):
        return ObjectAsset(object_id="t/bad", category="b", mesh_path=mesh, collision=shapes)

    with pytest.raises(AssetError, match="'t/bad' has no collision shapes"):
        sim.load_object(asset())
    with pytest.raises(AssetError, match=r"bad capsule size \(0.1,\)"):
        sim.load_object(asset(PrimitiveShape(kind="capsule", size=(0.1,))))
    with pytest.raises(AssetError, match="convex part .*missing.obj does not exist"):
        sim.load_object(asset(ConvexPart(path=tmp_path / "missing.obj")))


def test_hand_description_must_name_every_urdf_joint(hand):
    from dataclasses import replace

    from helpers_sim import TestHand

    d = hand.description
    partial = TestHand(replace(d, name="partial", joint_names=d.joint_names[:-1]), hand.urdf_path())
    with pytest.raises(AssetError, match=r"not in joint_names: \['joint_15.0'\]"):
        make_sim(partial)


def test_contact_offset_setting(hand):
    with pytest.raises(ConfigError, match=r"contact_offset=0.0 m; give a value in \(0, 0.1\]"):
        SapienBackend(SceneConfig(), contact_offset=0.0)
    obj, wrist, q = allegro_top_down(hand)
    listed = []
    for offset in (None, 0.002):
        sim = SapienBackend(SceneConfig(), contact_offset=offset)
        sim.load_hand(hand)
        sim.load_object(obj)
        sim.set_hand_state(q[None], wrist[None])
        sim.step(1)
        shapes = [s for link in sim._envs[0].hand.get_links() for s in link.get_collision_shapes()]
        assert {round(s.get_contact_offset(), 6) for s in shapes} == {offset or 0.01}
        listed.append(len(sim._envs[0].scene.get_contacts()))
    assert listed[1] < listed[0]  # fewer not-yet-touching pairs to scan


def test_scene_settings_reach_physx(hand):
    config = dict(timestep=1 / 240, solver_iterations=13, hand_friction=0.7, table_friction=0.4)
    sim = make_sim(hand, **config)
    sim.load_object(box_asset(friction=0.3))
    env = sim._envs[0]
    assert env.scene.get_timestep() == pytest.approx(1 / 240)
    for body in (env.hand, env.obj_body):
        assert body.get_solver_position_iterations() == 13
        assert body.get_sleep_threshold() == 0.0
    shapes = {
        "hand": [s for link in env.hand.get_links() for s in link.collision_shapes],
        "object": env.obj_body.collision_shapes,
        "table": env.scene.entities[0].components[0].collision_shapes,
    }
    frictions = {k: {round(s.physical_material.static_friction, 6) for s in v} for k, v in shapes.items()}
    assert frictions == {"hand": {0.7}, "object": {0.3}, "table": {0.4}}
    assert all(link.disable_gravity for link in env.hand.get_links())


def test_vulkan_warning_stays_out_of_ges_output():
    """``import sapien`` warns about the missing system libvulkan here; ``ges sim check`` must not show it."""
    raw = run_python("-c", "import sapien")
    if "libvulkan" not in raw.stderr:
        pytest.skip("this machine has a system libvulkan: SAPIEN has no warning to hide")
    args = ("--hand", "allegro", "--sim", "sapien", "-o", "close_steps=5", "-o", "lift_steps=0")
    ges = run_python("-m", "ges_core.cli", "sim", "check", *args)
    assert "hand allegro in sapien:" in ges.stdout, ges.stderr  # the check ran and printed its report
    assert "libvulkan" not in ges.stderr + ges.stdout


# -- the parsed hand, reused ----------------------------------------------------------------------
@pytest.mark.parametrize("self_collision", [True, False])
def test_a_hand_parsed_once_builds_what_a_fresh_parse_builds(hand, monkeypatch, self_collision):
    """The first backend parses the URDF, the next ones reuse the builder (with two envs: one parse for both); the
    fingers then close on a box in each, and every joint, fingertip pose and fingertip force of every step is
    bit-identical to the backend whose hand was parsed fresh."""
    from ges_plugins.sims.sapien import loading

    parses, parse = [], loading._parsed_hand
    monkeypatch.setattr(loading, "_parsed_hand", lambda *args: parses.append(args[1]) or parse(*args))
    monkeypatch.setattr(loading, "_HAND_BUILDERS", {})
    closed = np.asarray(hand.description.open_pose) + 0.6
    box = box_asset()

    def run(num_envs: int) -> list[np.ndarray]:
        sim = make_sim(hand, num_envs=num_envs, self_collision=self_collision)
        with sim:
            sim.load_object(box)
            sim.set_object_pose(np.tile([0.0, 0.0, 0.03, 1.0, 0.0, 0.0, 0.0], (num_envs, 1)))
            above = np.array([0.0, -0.02, 0.16, 0.0, 1.0, 0.0, 0.0])
            sim.set_hand_state(open_q(hand, num_envs), np.tile(above, (num_envs, 1)))
            trace = []
            for step in range(60):
                sim.set_joint_targets(np.tile(closed * min(1.0, step / 30), (num_envs, 1)))
                sim.step()
                trace += [sim.joint_state()[0], sim.link_poses(ALLEGRO_TIPS), sim.contact_forces(ALLEGRO_TIPS)]
            return [np.asarray(a)[:1] for a in trace]

    fresh = run(1)
    again, two_envs = run(1), run(2)
    assert len(parses) == 1  # one parse for all three backends and both envs of the last
    for a, b, c in zip(fresh, again, two_envs, strict=True):
        assert np.array_equal(a, b) and np.array_equal(a, c)
    assert any(np.abs(f).max() > 0 for f in fresh[2::3])  # the fingertips did touch the box

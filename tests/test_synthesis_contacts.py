"""Contact generation on the real procedural objects (trimesh meshes) and on malformed clouds."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from pydantic import ValidationError

from ges_core.dataset.layout import config_differences
from ges_core.errors import ConfigError, SynthesisError
from ges_core.objects.library import LibraryConfig, ObjectLibrary
from ges_core.synthesis import SynthesisConfig
from ges_core.synthesis.contacts.force_closure import ForceClosureConfig, ferrari_canny
from ges_core.synthesis.contacts.generate import ContactConfig, generate_contacts, squeeze_imbalance
from ges_core.synthesis.contacts.lift_friction import lift_capacity

CFG = ContactConfig()
PINCH = ContactConfig(thumb_balance_shifts=())
"""The thumb always opposite the index."""
THUMB, FINGERS = 0, slice(1, 5)
SIDE = np.array([1.0, -1.0, -1.0, -1.0, -1.0])
"""Thumb on the +squeeze side of the object, fingers on the -squeeze side."""


@pytest.fixture(scope="module")
def lib() -> ObjectLibrary:
    return ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=2))


@pytest.fixture(scope="module")
def clouds(lib) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {o.object_id: lib.point_cloud(o.object_id, 1024, seed=0) for o in lib.list()}


@pytest.fixture(scope="module")
def results(clouds) -> dict:
    return {oid: generate_contacts(p, n, CFG, object_id=oid) for oid, (p, n) in clouds.items()}


def ids(lib_ids: str) -> list[str]:
    return [f"procedural/{name}" for name in lib_ids.split()]


ALL = ids(
    "box/000 box/001 cube/000 cube/001 plate/000 plate/001 can/000 can/001 sphere/000 sphere/001 capsule/000 "
    "capsule/001 l_bracket/000 l_bracket/001 wedge/000 wedge/001 cone/000 cone/001 ellipsoid/000 ellipsoid/001 "
    "bottle/000 bottle/001 bowl/000 bowl/001 mug/000 mug/001 torus/000 torus/001 "
    "hammer/000 hammer/001 dumbbell/000 dumbbell/001 rod/000 rod/001 spray_can/000 spray_can/001 puck/000 puck/001 "
    "remote/000 remote/001 hex_prism/000 hex_prism/001 pyramid/000 pyramid/001 tri_prism/000 tri_prism/001 "
    "frustum/000 frustum/001 stamp/000 stamp/001 cross/000 cross/001 barrel/000 barrel/001 channel/000 channel/001"
)


def test_every_procedural_object_is_covered(lib):
    assert sorted(o.object_id for o in lib.list()) == sorted(ALL)


@pytest.mark.parametrize("oid", ids("can/000 can/001 bottle/000 bottle/001 mug/000"))
def test_tall_objects_are_grasped_from_the_side(results, oid):
    r = results[oid]
    assert r.strategy == "horizontal"
    assert abs(r.approach[2]) < 1e-9 and np.linalg.norm(r.approach) == pytest.approx(1.0)


@pytest.mark.parametrize("oid", ids("plate/000 plate/001 box/000 capsule/000 torus/000 sphere/000 cube/000"))
def test_flat_long_or_axisless_objects_are_grasped_from_above(results, oid):
    r = results[oid]
    assert r.strategy == "vertical"
    assert np.allclose(r.approach, [0.0, 0.0, -1.0])


@pytest.mark.parametrize(
    ("oid", "symmetric"),
    [(i, True) for i in ids("can/000 can/001 bottle/000 sphere/000 cone/001 bowl/001 torus/000")]
    + [(i, False) for i in ids("box/000 cube/000 plate/001 mug/000 mug/001 capsule/000 wedge/000 ellipsoid/000")],
)
def test_rotational_symmetry_is_detected_from_the_data(results, clouds, oid, symmetric):
    assert results[oid].symmetric is symmetric
    p, n = clouds[oid]
    rot = trimesh.transformations.rotation_matrix(0.7, [0, 0, 1])[:3, :3]
    moved = generate_contacts(p @ rot.T + [0.2, -0.1, 0.0], n @ rot.T, CFG)
    assert moved.symmetric is symmetric


@pytest.mark.parametrize("oid", ALL)
def test_contacts_lie_on_the_mesh_with_its_outward_normals(lib, results, oid):
    c = results[oid].contacts
    mesh = lib.processed(oid).mesh
    closest, dist, tri = trimesh.proximity.closest_point(mesh, c.positions)
    assert dist.max() < 1e-3
    assert np.einsum("ij,ij->i", mesh.face_normals[tri], c.normals).min() > 0.99
    assert c.positions[:, 2].min() >= CFG.min_height
    assert c.object_id == oid


@pytest.mark.parametrize("oid", ALL)
def test_thumb_and_fingers_can_reach_their_contacts(lib, results, oid):
    """A ray leaving each contact on its own side of the object (thumb +squeeze, fingers -squeeze)
    meets no other part of the mesh: no contact sits on an inner wall or in a hidden pocket."""
    c = results[oid].contacts
    out = SIDE[:, None] * np.asarray(c.meta["squeeze_axis"])[None, :]
    mesh = lib.processed(oid).mesh
    assert not mesh.ray.intersects_any(c.positions + 1e-3 * out, out).any()
    assert (np.einsum("ij,ij->i", c.normals, out) >= np.cos(np.deg2rad(CFG.max_normal_angle_deg)) - 1e-9).all()


@pytest.mark.parametrize("oid", ids("box/000 box/001 cube/000 plate/000 can/000 bottle/000 mug/000"))
def test_thumb_opposes_the_four_fingers(results, oid):
    n = results[oid].contacts.normals
    assert n[THUMB] @ n[FINGERS].mean(axis=0) < -0.5


@pytest.mark.parametrize("oid", ALL)
def test_layout_is_a_right_hand_with_a_thumb_index_pinch(results, clouds, oid):
    """Fingers in order along the spread axis at about the finger spacing; the thumb is across from the
    index (within half a spacing along the row: the pinch), or moved toward the row by at most the largest balance
    shift and then balanced at least as well (within thumb_balance_tol) as the contacts with the pinch kept;
    approach, thumb->fingers and index->little form a right-handed triad."""
    r = results[oid]
    p, meta = r.contacts.positions, r.contacts.meta
    s = p @ np.asarray(meta["spread_axis"])
    gaps = np.diff(s[FINGERS])
    spacing = meta["finger_spacing"]
    assert (gaps > 0.25 * spacing).all() and (gaps < 2.0 * spacing).all()
    if abs(s[THUMB] - s[1]) > 0.5 * spacing:
        assert 0.5 * spacing < s[THUMB] - s[1] <= (max(CFG.thumb_balance_shifts) + 0.5) * spacing
        pinch = generate_contacts(*clouds[oid], PINCH, object_id=oid).contacts.normals
        assert squeeze_imbalance(r.contacts.normals) <= squeeze_imbalance(pinch) + CFG.thumb_balance_tol
    d = p[FINGERS].mean(axis=0) - p[THUMB]
    d -= (d @ r.approach) * r.approach
    u = p[4] - p[1]
    assert np.cross(d, u) @ r.approach > 0


# tri_prism/000: an equilateral prism lying on a face; its slanted faces' normals are 30 deg above horizontal,
# steeper than atan(0.5) = 27 deg, so (like the wide cone below) a contact set across them has no force closure.
@pytest.mark.parametrize("oid", [i for i in ALL if i not in ids("cone/000 bowl/000 tri_prism/000")])
def test_contacts_are_in_force_closure(results, oid):
    assert results[oid].quality > 0.0


@pytest.mark.parametrize("oid", ids("box/000 can/000 sphere/000"))
def test_reported_quality_is_ferrari_canny_about_the_cloud_centroid(results, clouds, oid):
    p, _ = clouds[oid]
    c, centre = results[oid].contacts, p.mean(axis=0)
    radius = np.linalg.norm(p - centre, axis=1).max()
    assert results[oid].quality == pytest.approx(ferrari_canny(c.positions, c.normals, center=centre, radius=radius))


def test_a_cone_steeper_than_the_friction_angle_has_no_force_closure(results, clouds):
    """The wide cone's side normals are 34 deg above horizontal, steeper than atan(0.5) = 27 deg: every
    contact force then pushes down, so nothing resists a push from below. With mu = 1 it closes."""
    oid = "procedural/cone/000"
    n = results[oid].contacts.normals
    assert (n[:, 2] > np.sin(np.arctan(0.5))).all() and results[oid].quality == 0.0
    cfg = CFG.model_copy(update={"force_closure": ForceClosureConfig(mu=1.0)})
    assert generate_contacts(*clouds[oid], cfg).quality > 0.0


def test_layout_rank_walks_the_candidates_in_force_closure_until_they_run_out(results, clouds):
    """layout_rank 1, 2, ... give the next candidates in force closure, each new; past the last the reason is
    no_more_layouts. The cone, with none in force closure (the test above), has no rank 1."""
    oid = "procedural/box/000"
    seen = [results[oid].contacts.positions]
    for rank in range(1, 13):  # at most 2 strategies x 2 squeeze axes x 3 layouts
        try:
            found = generate_contacts(*clouds[oid], CFG.model_copy(update={"layout_rank": rank}), object_id=oid)
        except SynthesisError as error:
            assert error.reason == "no_more_layouts" and f"layout_rank={rank}" in str(error)
            break
        assert found.quality > 0.0
        assert not any(np.array_equal(found.contacts.positions, earlier) for earlier in seen)
        seen.append(found.contacts.positions)
    else:
        pytest.fail("more candidates than the search can make")
    assert len(seen) >= 3
    with pytest.raises(SynthesisError) as info:
        generate_contacts(*clouds["procedural/cone/000"], CFG.model_copy(update={"layout_rank": 1}))
    assert info.value.reason == "no_more_layouts"


def test_layout_rank_is_stored_only_when_set_so_older_datasets_resume():
    """A run at rank 0 stores the run_config it stored before the field existed (its hash is in every record)."""
    run = SynthesisConfig()
    assert "layout_rank" not in run.dump()["contacts"] and "lift_candidates" not in run.dump()["contacts"]
    assert SynthesisConfig.model_validate(run.dump()).contacts.layout_rank == 0
    ranked = SynthesisConfig.model_validate({"contacts": {"layout_rank": 2}})
    assert ranked.dump()["contacts"]["layout_rank"] == 2
    assert config_differences(run.dump(), ranked.dump()) == ["contacts.layout_rank: '<absent>' -> 2"]


def test_lift_candidates_pick_the_candidate_in_force_closure_that_lifts_most(clouds):
    """lift_candidates = N returns, of the first N candidates in force closure (layout_rank 0 .. N-1, walked
    independently here), the one with the largest lift_capacity about the cloud's centroid; 1 is the first."""
    changed = 0
    for oid in ids("box/000 sphere/000 bottle/000 stamp/000 capsule/001 hammer/000"):
        points, normals = clouds[oid]
        center = points.mean(axis=0)
        radius = float(np.linalg.norm(points - center, axis=1).max())
        ranked, first = [], CFG.model_copy(update={"lift_candidates": 1})
        for rank in range(3):
            try:
                ranked.append(generate_contacts(points, normals, first.model_copy(update={"layout_rank": rank})))
            except SynthesisError:
                break
        lifts = [lift_capacity(r.contacts.positions, r.contacts.normals, CFG.force_closure.mu, center, radius=radius)
                 for r in ranked]  # fmt: skip
        picked = generate_contacts(points, normals, CFG.model_copy(update={"lift_candidates": 3}))
        assert np.array_equal(picked.contacts.positions, ranked[int(np.argmax(lifts))].contacts.positions), oid
        changed += int(np.argmax(lifts)) != 0
    assert changed > 0  # the objects include some whose first candidate is not the one that lifts most
    with pytest.raises(ValidationError, match="layout_rank and lift_candidates"):
        ContactConfig(layout_rank=1, lift_candidates=2)


@pytest.mark.parametrize("oid", ids("box/000 mug/000 wedge/000 l_bracket/001"))
def test_contacts_turn_with_an_asymmetric_object(results, clouds, oid):
    """Full-PCA alignment makes the result equivariant: turn and shift the cloud, the contacts follow."""
    p, n = clouds[oid]
    rot = trimesh.transformations.rotation_matrix(2.0, [0, 0, 1])[:3, :3]
    shift = np.array([0.3, 0.1, 0.0])
    moved = generate_contacts(p @ rot.T + shift, n @ rot.T, CFG)
    ref = results[oid]
    assert np.allclose(moved.contacts.positions, ref.contacts.positions @ rot.T + shift, atol=1e-9)
    assert np.allclose(moved.approach, rot @ ref.approach)
    assert moved.quality == pytest.approx(ref.quality, rel=1e-6)


def test_same_input_and_seed_give_identical_results(clouds):
    p, n = clouds["procedural/mug/000"]
    a, b = generate_contacts(p, n, CFG, seed=3), generate_contacts(p, n, CFG, seed=3)
    assert np.array_equal(a.contacts.positions, b.contacts.positions)
    assert np.array_equal(a.contacts.normals, b.contacts.normals)
    assert a.quality == b.quality and a.contacts.meta == b.contacts.meta


def test_seed_picks_the_subsample_of_a_large_cloud(lib):
    p, n = lib.point_cloud("procedural/box/001", 3000, seed=0)
    cfg = CFG.model_copy(update={"max_points": 1024})
    a, b, c = (generate_contacts(p, n, cfg, seed=s) for s in (0, 0, 1))
    assert np.array_equal(a.contacts.positions, b.contacts.positions)
    assert not np.array_equal(a.contacts.positions, c.contacts.positions)
    assert c.quality > 0.0 and c.strategy == a.strategy
    for r in (a, c):
        rows = r.contacts.meta["point_indices"]
        assert np.array_equal(r.contacts.positions, p[rows]) and np.allclose(r.contacts.normals, n[rows])


# ---- bad input -------------------------------------------------------------------------------------


def box_cloud(size, n: int = 600, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.creation.box(extents=size)
    mesh.apply_translation([0.0, 0.0, size[2] / 2])
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts, mesh.face_normals[face]


def flat_disc() -> tuple[np.ndarray, np.ndarray]:
    xy = np.random.default_rng(0).uniform(-0.04, 0.04, size=(200, 2))
    return np.column_stack([xy, np.full(200, 0.03)]), np.tile([0.0, 0.0, 1.0], (200, 1))


def line() -> tuple[np.ndarray, np.ndarray]:
    z = np.linspace(0.0, 0.1, 100)
    return np.column_stack([np.zeros(100), np.zeros(100), z]), np.tile([1.0, 0.0, 0.0], (100, 1))


def with_nan(normals: bool) -> tuple[np.ndarray, np.ndarray]:
    p, n = box_cloud((0.06, 0.05, 0.08))
    (n if normals else p)[7, 1] = np.inf if normals else np.nan
    return p, n


def inside_out() -> tuple[np.ndarray, np.ndarray]:
    p, n = box_cloud((0.06, 0.05, 0.08))
    return p, -n


BAD = {
    "empty": (lambda: (np.zeros((0, 3)), np.zeros((0, 3))), "empty_cloud", "empty"),
    "nan point": (lambda: with_nan(False), "nan_in_cloud", "NaN or inf"),
    "inf normal": (lambda: with_nan(True), "nan_in_cloud", "NaN or inf"),
    "single point": (
        lambda: (np.array([[0.0, 0.0, 0.05]]), np.array([[0.0, 0.0, 1.0]])),
        "degenerate_cloud",
        "1 points",
    ),
    "flat": (flat_disc, "degenerate_cloud", "flat, collinear or a point"),
    "collinear": (line, "degenerate_cloud", "flat, collinear or a point"),
    "shape": (lambda: (np.zeros((30, 2)), np.zeros((30, 2))), "bad_input", "(N, 3)"),
    "mismatch": (lambda: (np.zeros((30, 3)), np.zeros((29, 3))), "bad_input", "(N, 3)"),
    "zero normals": (lambda: (box_cloud((0.06, 0.05, 0.08))[0], np.zeros((600, 3))), "bad_input", "zero length"),
    "huge object": (lambda: box_cloud((0.6, 0.5, 0.4)), "no_graspable_width", "too wide or too thin"),
    "thin rod": (lambda: box_cloud((0.003, 0.003, 0.1)), "no_graspable_width", "too wide or too thin"),
    "too low": (lambda: box_cloud((0.06, 0.05, 0.008)), "too_low", "min_height"),
    "inside out": (inside_out, "no_contact_surface", "faces the thumb or a finger"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_clouds_raise_synthesis_error_with_a_reason(case):
    make, reason, needle = BAD[case]
    points, normals = make()
    with pytest.raises(SynthesisError) as err:
        generate_contacts(points, normals, CFG, object_id="test/bad")
    assert err.value.reason == reason
    assert needle in str(err.value) and "test/bad" in str(err.value)


def test_a_valid_box_cloud_passes_the_same_checks():
    r = generate_contacts(*box_cloud((0.06, 0.05, 0.08)), CFG)
    assert r.quality > 0.0 and r.seconds > 0.0


def test_config_rejects_unknown_and_out_of_range_fields():
    for bad in ({"min_height": -0.01}, {"max_normal_angle_deg": 95.0}, {"fingers": 4}):
        with pytest.raises(ValidationError):
            ContactConfig(**bad)
    with pytest.raises(ValidationError, match=r"min_width \(0.2\) must be below max_width"):
        ContactConfig(min_width=0.2)


def test_squeeze_imbalance_is_the_net_normal_force_of_a_thumb_as_strong_as_the_four_fingers():
    """Checked against forces written out by hand: the thumb pushes 4 units, each finger 1, along -normal."""
    across = np.array([[0, 1.0, 0]] + [[0, -1.0, 0]] * 4)
    assert squeeze_imbalance(across) == 0.0
    turned = across.copy()
    turned[THUMB] = [1.0, 0, 0]  # the thumb pushes along -x, the fingers along +y
    assert squeeze_imbalance(turned) == pytest.approx(np.linalg.norm([-4.0, 4.0]) / 8)


@pytest.mark.parametrize(("mesh", "moves"), [(trimesh.creation.cylinder(0.04, 0.025), True),
                                               (trimesh.creation.box([0.07, 0.05, 0.03]), False)])  # fmt: skip
def test_the_thumb_leaves_the_pinch_only_where_the_squeeze_would_not_balance(mesh, moves):
    """A puck grasped from above: the thumb opposite the index sits off the fingers' resultant on the round rim,
    so it moves toward the row and the squeeze balances better; a box's flat faces balance at the pinch, which
    stays (the same contacts as with the balance off)."""
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    points, faces = trimesh.sample.sample_surface(mesh, 1024, seed=0)
    normals = mesh.face_normals[faces]
    pinch = generate_contacts(points, normals, PINCH, object_id="t")
    balanced = generate_contacts(points, normals, CFG, object_id="t")
    if moves:
        assert squeeze_imbalance(pinch.contacts.normals) > CFG.thumb_balance_tol
        assert squeeze_imbalance(balanced.contacts.normals) < 0.5 * squeeze_imbalance(pinch.contacts.normals)
        s = balanced.contacts.positions @ np.asarray(balanced.contacts.meta["spread_axis"])
        assert s[THUMB] - s[1] > 0.5 * balanced.contacts.meta["finger_spacing"]
    else:
        np.testing.assert_array_equal(balanced.contacts.positions, pinch.contacts.positions)


def test_squeeze_imbalance_with_points_adds_the_torque_of_a_thumb_off_the_fingers_middle():
    """Flat faces, the thumb pushing 4 units and each finger 1 across them: the net force is 0 wherever the thumb is,
    and with the points the torque counts, written out by hand: the thumb at x = -3 cm against fingers centred at
    x = 0 turns the object about z by 4 x 0.03 N·m per unit force; opposite their middle, nothing. A balanced force
    leaves the torque the same about any point, so the centre does not matter."""
    normals = np.array([[0, 1.0, 0]] + [[0, -1.0, 0]] * 4)
    fingers = [[x, -0.01, 0.02] for x in (-0.03, -0.01, 0.01, 0.03)]
    at_end = np.array([[-0.03, 0.01, 0.02], *fingers])
    middle = np.array([[0.0, 0.01, 0.02], *fingers])
    radius = 0.05
    assert squeeze_imbalance(normals) == 0.0
    torque_z = 4 * 0.03  # thumb force (0, -4, 0) at x = -0.03: (r x f)_z = -0.03 * -4; the fingers' cancel about x=0
    expected = torque_z / radius / 8
    for center in (np.zeros(3), np.array([0.02, -0.04, 0.05])):
        assert squeeze_imbalance(normals, at_end, center=center, radius=radius) == pytest.approx(expected)
        assert squeeze_imbalance(normals, middle, center=center, radius=radius) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ConfigError, match="give center"):
        squeeze_imbalance(normals, at_end)


def test_a_balanced_torque_moves_the_thumb_off_the_pinch_on_a_long_flat_box():
    """A long box lying flat, grasped from above across its width: the pinch puts the thumb opposite the index, at
    one end of the finger row, and the flat faces balance the force there (the default keeps it); counting the torque
    too, the thumb moves toward the middle of the row and the squeeze's wrench balances better."""
    mesh = trimesh.creation.box([0.10, 0.04, 0.03])
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    points, faces = trimesh.sample.sample_surface(mesh, 1024, seed=0)
    normals = mesh.face_normals[faces]
    pinch = generate_contacts(points, normals, CFG, object_id="t")
    torque = generate_contacts(points, normals, ContactConfig(thumb_balance_torque=True), object_id="t")
    center, radius = points.mean(axis=0), float(np.linalg.norm(points - points.mean(axis=0), axis=1).max())

    def wrench(r):
        return squeeze_imbalance(r.contacts.normals, r.contacts.positions, center=center, radius=radius)

    s_pinch = pinch.contacts.positions @ np.asarray(pinch.contacts.meta["spread_axis"])
    s_torque = torque.contacts.positions @ np.asarray(torque.contacts.meta["spread_axis"])
    spacing = torque.contacts.meta["finger_spacing"]
    assert abs(s_pinch[THUMB] - s_pinch[1]) < 0.5 * spacing  # the default: the pinch
    assert s_torque[THUMB] - s_torque[1] > 0.5 * spacing  # moved toward the row
    assert abs(s_torque[THUMB] - s_torque[FINGERS].mean()) < abs(s_pinch[THUMB] - s_pinch[FINGERS].mean())
    assert wrench(torque) < wrench(pinch)


@pytest.mark.parametrize("oid", ids("box/000 bottle/000"))  # grasped from above / from the side
def test_thumb_shift_moves_the_thumb_toward_the_finger_row_in_both_strategies(clouds, oid):
    """thumb_shift = 1 puts the thumb about one spacing from the index toward the little finger (before, a side
    grasp moved it the other way, above the index)."""
    shifted = ContactConfig(thumb_shift=1.0, thumb_balance_shifts=())
    r = generate_contacts(*clouds[oid], shifted, object_id=oid)
    s = r.contacts.positions @ np.asarray(r.contacts.meta["spread_axis"])
    spacing = r.contacts.meta["finger_spacing"]
    assert 0.5 * spacing < s[THUMB] - s[1] < 1.5 * spacing, (r.strategy, (s[THUMB] - s[1]) / spacing)

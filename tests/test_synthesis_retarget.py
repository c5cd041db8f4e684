"""Grasp retargeting: the batched joint solver, topology descriptors, wrist placement, bad input.

Reachable targets are fingertip points of random joint values (our FK, itself checked against
PyBullet in test_kinematics.py); wrist placement is checked by composing the returned base pose
with FK independently of the retargeter's own frame conversions.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh
from pydantic import ValidationError

from ges_core.collision_points import collision_points
from ges_core.contact import FINGER_SLOTS, ContactSet
from ges_core.errors import ArrayError, AssetError, SynthesisError
from ges_core.hand import HandModel
from ges_core.kinematics import HandKinematics
from ges_core.objects.pointcloud import sample_surface
from ges_core.registry import load_registry
from ges_core.synthesis.retarget.retargeter import GraspRetargeter, RetargetConfig, raise_contacts, retarget_contacts
from ges_core.synthesis.retarget.search import (
    ObjectCloud,
    WristSearchConfig,
    candidate_wrists,
    distinct_ranking,
    object_penalty,
)
from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter
from ges_core.synthesis.retarget.wrist import (
    check_contact_array,
    contact_problems,
    coupling_rotation,
    hand_frame,
    topology_descriptors,
)
from ges_core.synthesis.types import Grasp
from ges_core.transforms import pose_to_matrix

HANDS = ("allegro", "shadow")


@pytest.fixture(scope="module")
def hands() -> dict[str, HandModel]:
    registry = load_registry()
    return {name: registry.build_hand(name) for name in HANDS}


@pytest.fixture(scope="module")
def kins(hands) -> dict[str, HandKinematics]:
    return {name: HandKinematics.from_hand(hand) for name, hand in hands.items()}


@pytest.fixture(scope="module")
def solvers(hands, kins) -> dict[str, VectorRetargeter]:
    return {name: VectorRetargeter(hands[name], kinematics=kins[name]) for name in HANDS}


def random_finger_q(hand: HandModel, n: int, seed: int) -> torch.Tensor:
    """(n, K) uniform finger joints within limits, other joints (Shadow's wrist) open, couplings applied."""
    d = hand.description
    lim = d.limits_array
    q = np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(n, d.num_joints))
    finger_joints = {j for f in d.fingers for j in f.joints}
    fixed = [i for i, name in enumerate(d.joint_names) if name not in finger_joints]
    q[:, fixed] = np.asarray(d.open_pose)[fixed]
    return torch.as_tensor(d.apply_couplings(q))


# -- the joint solver ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", HANDS)
@pytest.mark.parametrize(
    ("seeds", "closure"), [(512, 0.0), (0, 0.3)], ids=["start-table-from-open", "cold-from-30pct-closed"]
)
def test_reaches_reachable_targets(hands, kins, name, seeds, closure):
    hand = hands[name]
    solver = VectorRetargeter(hand, VectorRetargetConfig(seeds=seeds, iterations=10), kinematics=kins[name])
    targets = solver.fingertips(random_finger_q(hand, 32, seed=1))
    q0 = torch.as_tensor(hand.description.closed_pose(closure)).expand(32, -1)
    q, residual = solver.solve(targets, q0)
    err = (solver.fingertips(q) - targets).norm(dim=-1)
    assert err.mean() < 1e-3, f"{name}: mean fingertip error {err.mean() * 1e3:.3f} mm"
    assert torch.allclose(residual, err.mean(dim=1), atol=1e-12)


@pytest.mark.parametrize("name", HANDS)
def test_limits_and_couplings_hold_for_unreachable_targets(hands, solvers, name):
    d = hands[name].description
    targets = torch.as_tensor(np.random.default_rng(2).normal(scale=0.4, size=(16, 5, 3)))  # mostly out of reach
    q, residual = solvers[name].solve(targets)
    lim = torch.as_tensor(d.limits_array)
    assert (q >= lim[:, 0]).all() and (q <= lim[:, 1]).all()
    np.testing.assert_allclose(d.apply_couplings(q.numpy()), q.numpy(), atol=1e-12)
    assert (residual > 0.05).any()  # the targets really were out of reach
    # Each fingertip is measured against the point its finger aims at: the slot's own target, or for a finger
    # serving two slots their mean, which by the triangle inequality is never farther than the two on average.
    own = (solvers[name].fingertips(q) - targets).norm(dim=-1).mean(dim=1)
    if d.slot_fill:  # Allegro: its ring serves ring and little, whose random targets differ
        assert (residual <= own + 1e-12).all() and (residual < own - 1e-4).all()
    else:
        torch.testing.assert_close(residual, own, atol=1e-12, rtol=0)


def test_shadow_followers_track_leaders(hands, solvers):
    d = hands["shadow"].description
    q, _ = solvers["shadow"].solve(solvers["shadow"].fingertips(random_finger_q(hands["shadow"], 16, seed=3)))
    for c in d.couplings:
        fol, lead = d.joint_index([c.follower, c.leader])
        expected = np.clip(c.ratio * q[:, lead].numpy(), *d.limits_array[fol])
        np.testing.assert_allclose(q[:, fol].numpy(), expected, atol=1e-12)
    assert len(d.couplings) == 4


def test_non_finger_joints_stay_at_q_init(hands, solvers):
    d = hands["shadow"].description
    q0 = torch.as_tensor(d.closed_pose(0.2)).expand(4, -1).clone()
    q0[:, :2] = torch.tensor([-0.3, 0.1])  # WRJ1, WRJ0
    targets = solvers["shadow"].fingertips(random_finger_q(hands["shadow"], 4, seed=4))
    q, _ = solvers["shadow"].solve(targets, q0)
    assert d.joint_names[:2] == ("WRJ1", "WRJ0")
    assert torch.equal(q[:, :2], q0[:, :2])


def test_beta_pulls_toward_q_prev(hands, kins):
    hand = hands["allegro"]
    q_target = random_finger_q(hand, 8, seed=5)
    q_prev = random_finger_q(hand, 8, seed=6)
    distances, errors = [], []
    for beta in (0.0, 1e-4, 1.0):
        config = VectorRetargetConfig(beta=beta, seeds=0, iterations=15)
        solver = VectorRetargeter(hand, config, kinematics=kins["allegro"])
        targets = solver.fingertips(q_target)
        q, residual = solver.solve(targets, q_init=q_prev, q_prev=q_prev)
        distances.append(float((q - q_prev).norm(dim=1).mean()))
        errors.append(float(residual.mean()))
    assert distances[0] > distances[1] > distances[2], distances
    assert errors[0] < errors[1] < errors[2], errors
    assert distances[2] < 0.1 * distances[0], distances


@pytest.mark.parametrize("name", HANDS)
def test_batch_equals_one_by_one(hands, solvers, name):
    solver = solvers[name]
    targets = solver.fingertips(random_finger_q(hands[name], 6, seed=7))
    targets = targets + torch.as_tensor(np.random.default_rng(8).normal(scale=0.01, size=targets.shape))
    q_batch, res_batch = solver.solve(targets)
    for i in range(len(targets)):
        q_one, res_one = solver.solve(targets[i : i + 1])
        torch.testing.assert_close(q_one[0], q_batch[i], atol=1e-9, rtol=0)
        torch.testing.assert_close(res_one[0], res_batch[i], atol=1e-9, rtol=0)


def test_finger_serving_two_slots_aims_at_their_mean(hands, solvers):
    solver = solvers["allegro"]
    targets = solver.fingertips(random_finger_q(hands["allegro"], 4, seed=9))
    ring, little = FINGER_SLOTS.index("ring"), FINGER_SLOTS.index("little")
    split = targets.clone()
    split[:, ring, 2] += 0.01
    split[:, little, 2] -= 0.01  # same mean, 2 cm apart
    q, residual = solver.solve(split)
    tips = solver.fingertips(q)
    torch.testing.assert_close(tips[:, ring], targets[:, ring], atol=1e-4, rtol=0)
    # The residual measures each fingertip against the point its finger aims at (here the ring and little
    # targets' mean), so a contact layout with more contacts than the hand has fingers is not "unreachable"
    # for that alone; measured against each slot's own target it would be 2 x 1 cm / 5 slots = 4 mm.
    aims = split.clone()
    aims[:, ring] = aims[:, little] = (split[:, ring] + split[:, little]) / 2
    torch.testing.assert_close(residual, (tips - aims).norm(dim=-1).mean(dim=1), atol=1e-12, rtol=0)
    assert residual.max() < 1e-4
    assert ((tips - split).norm(dim=-1).mean(dim=1) > 0.2 * 0.02 - 1e-4).all()


def pad_normals(kin: HandKinematics, hand: HandModel, q: torch.Tensor) -> torch.Tensor:
    """(B, S, 3) pad normal of the finger serving each slot at q, base frame (independent of the solver)."""
    d = hand.description
    rot = kin.link_poses(q, [d.finger_for_slot(s).tip_link for s in FINGER_SLOTS])[..., :3, :3]
    pads = torch.tensor([d.finger_for_slot(s).pad_normal for s in FINGER_SLOTS], dtype=rot.dtype)
    return torch.einsum("bsij,sj->bsi", rot, pads)


@pytest.mark.parametrize("name", HANDS)
def test_pad_term_turns_each_pad_to_face_its_surface(hands, kins, name):
    """Targets and surfaces of reachable poses: with normals the pads face them, without they need not."""
    hand, kin = hands[name], kins[name]
    solver = VectorRetargeter(hand, VectorRetargetConfig(iterations=15), kinematics=kin)
    q_true = random_finger_q(hand, 32, seed=11)
    targets, normals = solver.fingertips(q_true), -pad_normals(kin, hand, q_true)  # surface faces the pad
    alignment = {}
    for with_normals in (False, True):
        q, residual = solver.solve(targets, normals=normals if with_normals else None)
        cos = (pad_normals(kin, hand, q) * -normals).sum(-1)
        alignment[with_normals] = float(cos.mean())
        assert residual.mean() < 3e-3, f"{name}: fingertip error {residual.mean() * 1e3:.2f} mm"
    # misalignment 1 - cos: Allegro's 4-joint fingers have little freedom (0.04 -> 0.002), Shadow's thumb much
    assert alignment[True] > 0.95 and 1 - alignment[True] < 0.5 * (1 - alignment[False]), alignment


def test_objective_is_the_squared_fingertip_distance_without_normals(hands, solvers):
    hand, solver = hands["shadow"], solvers["shadow"]  # one finger per slot: no slot averaging
    q = random_finger_q(hand, 5, seed=12)
    targets = solver.fingertips(random_finger_q(hand, 5, seed=13))
    expected = ((solver.fingertips(q) - targets) ** 2).sum(dim=(1, 2))
    torch.testing.assert_close(solver.objective(q, targets), expected, atol=1e-12, rtol=0)
    thumb = FINGER_SLOTS.index("thumb")  # the Shadow's fingers are its slots, in slot order
    expected_thumb = ((solver.fingertips(q)[:, thumb] - targets[:, thumb]) ** 2).sum(-1)
    torch.testing.assert_close(solver.finger_objective(q, targets)[:, solver.thumb_finger], expected_thumb)


# -- topology descriptors ------------------------------------------------------------------------
def rotation(seed: int) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.random(random_state=seed).as_matrix()


def top_grasp(half_width: float = 0.03, spacing: float = 0.025, height: float = 0.05) -> np.ndarray:
    """(5, 3) right-hand top-down grasp of a box: thumb on the -x face opposite the middle finger, fingers on +x,
    index at +y."""
    ys = np.array([1.5, 0.5, -0.5, -1.5]) * spacing
    return np.array([[-half_width, ys[1], height]] + [[half_width, y, height] for y in ys])


def test_palm_normal_is_orthogonal_to_a_planar_contact_set():
    rng = np.random.default_rng(10)
    planar = np.concatenate([rng.uniform(-0.01, 0.01, size=(8, 5, 2)), np.zeros((8, 5, 1))], axis=2)
    planar[:, :, 0] += np.array([-0.06, 0.04, 0.05, 0.04, 0.03])  # thumb apart from the fingers
    planar[:, :, 1] += np.array([0.0, 0.06, 0.02, -0.02, -0.06])  # index .. little spread along -y
    rots = np.stack([rotation(s) for s in range(8)])
    pos = np.einsum("bij,bsj->bsi", rots, planar) + rng.normal(size=(8, 1, 3))
    topo = topology_descriptors(pos)
    plane_normal = rots[:, :, 2]
    np.testing.assert_allclose(np.abs(np.sum(topo.palm_normal * plane_normal, axis=1)), 1.0, atol=1e-9)
    basis = topo.basis
    np.testing.assert_allclose(basis.transpose(0, 2, 1) @ basis, np.broadcast_to(np.eye(3), (8, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(basis), 1.0, atol=1e-12)  # right hand: n = d x u


def test_descriptors_of_a_top_down_box_grasp():
    topo = topology_descriptors(top_grasp())
    np.testing.assert_allclose(topo.palm_normal[0], [0, 0, -1], atol=1e-12)  # palm above, facing down
    np.testing.assert_allclose(topo.grasp_axis[0], [1, 0, 0], atol=1e-12)  # thumb -> middle
    np.testing.assert_allclose(topo.lateral_axis[0], [0, -1, 0], atol=1e-12)  # toward the little finger
    np.testing.assert_allclose(topo.center[0], top_grasp().mean(axis=0))
    left = topology_descriptors(top_grasp() * [1, -1, 1], chirality=-1.0)  # mirror image for a left hand
    np.testing.assert_allclose(left.palm_normal[0], [0, 0, -1], atol=1e-12)


def test_coupling_rotation_pitches_fingers_toward_the_object_and_pronates():
    r = coupling_rotation(10.0, 20.0, 1.0)  # columns: where d, u, n go, in (d, u, n) coordinates
    assert np.isclose(np.linalg.det(r), 1.0)
    assert r[2, 0] > 0.3  # the finger direction d gains a component along n (toward the object)
    assert np.isclose(r[0, 0], np.cos(np.radians(20.0)))  # d turned by the 20 degree pitch
    assert coupling_rotation(10.0, 0.0, 1.0)[1, 2] > 0  # pronation: n tilts toward the little-finger side


# -- wrist placement -----------------------------------------------------------------------------
@pytest.fixture(scope="module")
def retargeters(hands, kins) -> dict[str, GraspRetargeter]:
    return {name: GraspRetargeter(hands[name], kinematics=kins[name]) for name in HANDS}


def box_contact_sets() -> list[ContactSet]:
    normals = np.array([[-1.0, 0, 0]] + [[1.0, 0, 0]] * 4)
    return [
        ContactSet(top_grasp(hw, sp), normals, f"box_{hw}_{sp}") for hw in (0.02, 0.03, 0.04) for sp in (0.02, 0.03)
    ]


@pytest.mark.parametrize("name", HANDS)
def test_box_grasp_puts_fingertips_on_the_contacts(hands, kins, retargeters, name):
    d = hands[name].description
    contacts = box_contact_sets()
    grasps = retargeters[name].retarget_many(contacts)
    errors = []
    for g, c in zip(grasps, contacts, strict=True):
        assert isinstance(g, Grasp) and g.hand == name and g.q.shape == (d.num_joints,)
        base = pose_to_matrix(g.wrist_pose)
        tips = kins[name].points(torch.as_tensor(g.q)[None], list(d.tip_links), [f.tip_offset for f in d.fingers])
        tips = tips[0].numpy() @ base[:3, :3].T + base[:3, 3]  # object frame
        for finger, tip in zip(d.fingers, tips, strict=True):
            slots = [FINGER_SLOTS.index(s) for s in FINGER_SLOTS if d.finger_for_slot(s).name == finger.name]
            errors.append(np.linalg.norm(tip - c.positions[slots].mean(axis=0)))
        wrist_link = base @ kins[name].link_poses(torch.as_tensor(g.q)[None], [d.wrist.link])[0, 0].numpy()
        assert (wrist_link[:3, 3] - c.positions.mean(axis=0))[2] > 0.03  # the hand is above the contacts
        assert g.meta["reached"] and g.meta["residual"] < 0.02
    mean_mm, max_mm = np.mean(errors) * 1e3, np.max(errors) * 1e3
    print(f"{name}: box grasp, fingertip to its contact(s) mean {mean_mm:.2f} mm, max {max_mm:.2f} mm")
    assert mean_mm < 5.0, f"mean {mean_mm:.2f} mm"


def finger_objective(retargeter: GraspRetargeter, grasp: Grasp, contacts: ContactSet) -> np.ndarray:
    """(F,) each finger's solver objective at a returned grasp, recomputed from its base pose (object -> base)."""
    base = pose_to_matrix(grasp.wrist_pose)
    rot, trans = base[:3, :3], base[:3, 3]
    positions = raise_contacts(contacts.positions[None], retargeter.config.min_contact_height)[0]
    targets = torch.as_tensor(((positions - trans) @ rot)[None])
    normals = torch.as_tensor((contacts.normals @ rot)[None])
    return retargeter.solver.finger_objective(torch.as_tensor(grasp.q)[None], targets, normals)[0].numpy()


def grasp_objective(retargeter: GraspRetargeter, grasp: Grasp, contacts: ContactSet) -> float:
    """The solver objective of a returned grasp (every finger weighted by its slot count alone)."""
    return float(finger_objective(retargeter, grasp, contacts).sum())


@pytest.mark.parametrize("name", HANDS)
def test_wrist_search_fits_at_least_as_well_as_the_papers_placement(hands, kins, retargeters, name):
    paper = GraspRetargeter(hands[name], RetargetConfig(wrist_search={"enabled": False}), kinematics=kins[name])
    assert len(paper.search_offsets) == 1 and not paper.search_offsets.any()
    # fit only: with the table penalty on, a placement may fit worse to keep the hand off the table
    searched = GraspRetargeter(hands[name], RetargetConfig(wrist_search={"table_weight": 0.0}), kinematics=kins[name])
    offsets, ws = searched.search_offsets, searched.config.wrist_search
    assert not offsets[0].any() and len(offsets) == ws.candidates + ws.lateral_candidates  # row 0: the paper's
    assert not offsets[: ws.candidates, 5].any() and set(offsets[ws.candidates :, 5]) == set(ws.lateral)
    better = 0
    for contacts in box_contact_sets():
        a, b = (
            grasp_objective(paper, paper.retarget(contacts), contacts),
            grasp_objective(searched, searched.retarget(contacts), contacts),
        )
        assert b <= a + 1e-12
        better += b < 0.5 * a
    assert better >= 1, f"{name}: the search never halved the objective"


@pytest.mark.parametrize("name", HANDS)
def test_thumb_weight_trades_the_other_fingers_fit_for_the_thumbs(hands, kins, name):
    """The fingers are solved apart, so the thumb's weight only ranks the placements: raising it can only lower the
    thumb's fit term at the winning placement and raise the others' (the argmin of a sum with one term weighted
    more), and on these boxes it does move the wrist."""
    plain, thumbed = (
        GraspRetargeter(hands[name], RetargetConfig(wrist_search={"thumb_weight": w}), kinematics=kins[name])
        for w in (1.0, 8.0)
    )
    contacts = box_contact_sets()
    thumb, moved = plain.solver.thumb_finger, 0
    for c, a, b in zip(contacts, plain.retarget_many(contacts), thumbed.retarget_many(contacts), strict=True):
        fa, fb = finger_objective(plain, a, c), finger_objective(plain, b, c)
        assert fb[thumb] <= fa[thumb] + 1e-12, (c.object_id, fa, fb)
        assert np.delete(fb, thumb).sum() >= np.delete(fa, thumb).sum() - 1e-12, (c.object_id, fa, fb)
        moved += fb[thumb] < 0.5 * fa[thumb]
    assert moved >= 2, f"{name}: the thumb's weight halved its fit term on {moved} of {len(contacts)} boxes"


def test_lateral_slide_moves_the_wrist_along_the_lateral_axis(hands, kins):
    """A candidate slid by s along u_palm is the unslid one translated by s * u_palm, rotation unchanged."""
    r = GraspRetargeter(hands["allegro"], kinematics=kins["allegro"])
    pos = raise_contacts(np.stack([c.positions for c in box_contact_sets()]), 0.0)
    topo = topology_descriptors(pos, r.frame.chirality)
    offsets = np.array([[20.0, 0.0, 20.0, -0.15, -0.02, 0.0], [20.0, 0.0, 20.0, -0.15, -0.02, -0.02]])
    c = r.config
    kw = {"roll_deg": c.roll_deg, "pitch_deg": c.pitch_deg, "palm_distance": c.palm_distance, "y_d": c.y_d}
    wrists = candidate_wrists(topo, r.frame, offsets, **kw)
    np.testing.assert_allclose(wrists[:, 1, :3, :3], wrists[:, 0, :3, :3], atol=1e-12)
    np.testing.assert_allclose(wrists[:, 1, :3, 3] - wrists[:, 0, :3, 3], -0.02 * topo.lateral_axis, atol=1e-12)


def test_wrist_search_result_does_not_depend_on_batch_mates(retargeters):
    contacts = box_contact_sets()
    together = retargeters["shadow"].retarget_many(contacts[:3])
    for c, g in zip(contacts[:3], together, strict=True):
        alone = retargeters["shadow"].retarget(c)
        np.testing.assert_allclose(alone.wrist_pose, g.wrist_pose, atol=1e-12)
        np.testing.assert_allclose(alone.q, g.q, atol=1e-9)


def rotation_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle of the rotation between two (3, 3) rotation matrices, degrees (via scipy, independent of the code)."""
    from scipy.spatial.transform import Rotation

    return float(np.degrees((Rotation.from_matrix(a).inv() * Rotation.from_matrix(b)).magnitude()))


@pytest.mark.parametrize("name", HANDS)
def test_ranked_grasps_start_with_the_best_and_differ_in_placement(retargeters, name):
    r, config = retargeters[name], retargeters[name].config.wrist_search
    contacts = box_contact_sets()
    ranked = r.retarget_ranked(contacts, keep=3)
    best = r.retarget_many(contacts)
    assert any(len(grasps) > 1 for grasps in ranked)  # the search found alternatives
    for grasps, first in zip(ranked, best, strict=True):
        assert 1 <= len(grasps) <= 3
        np.testing.assert_allclose(grasps[0].wrist_pose, first.wrist_pose, atol=1e-12)
        np.testing.assert_allclose(grasps[0].q, first.q, atol=1e-12)
        wrists = [pose_to_matrix(g.wrist_pose) @ r.base_to_wrist for g in grasps]  # wrist links, object frame
        for i, later in enumerate(grasps[1:], start=1):
            assert later.meta["reached"]
            for before in wrists[:i]:
                apart = np.linalg.norm(wrists[i][:3, 3] - before[:3, 3]) >= config.distinct_distance - 1e-9
                turned = rotation_angle_deg(before[:3, :3], wrists[i][:3, :3]) >= config.distinct_deg - 1e-6
                assert apart or turned
    assert all(len(g) == 1 for g in r.retarget_ranked(contacts, keep=1))
    with pytest.raises(ValueError, match="keep must be at least 1"):
        r.retarget_ranked(contacts, keep=0)


def test_distinct_ranking_orders_by_cost_and_skips_near_and_ineligible_placements():
    from scipy.spatial.transform import Rotation

    config = WristSearchConfig(distinct_deg=15.0, distinct_distance=0.02)
    wrists = np.tile(np.eye(4), (6, 1, 1))
    wrists[1, :3, 3] = [0.01, 0, 0]  # 1 cm from 0, same rotation: too near
    wrists[2, :3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix()  # turned 20 deg: distinct
    wrists[3, :3, 3] = [0.0, 0.03, 0.0]  # 3 cm away: distinct, but not eligible
    wrists[4, :3, 3] = [0.0, 0.0, 0.025]  # 2.5 cm away: distinct
    wrists[5, :3, :3] = Rotation.from_euler("z", 25, degrees=True).as_matrix()  # 5 deg from 2: too near it
    cost = np.array([0.5, 0.1, 0.3, 0.2, 0.6, 0.4])
    eligible = np.array([True, True, True, False, True, True])
    assert distinct_ranking(cost, wrists, eligible, 10, config) == [1, 2, 4]  # 0 is 1 cm from 1; 5 near 2
    assert distinct_ranking(cost, wrists, eligible, 2, config) == [1, 2]
    assert distinct_ranking(cost, wrists, ~eligible, 10, config) == [1, 3]  # the best is kept even if ineligible
    assert distinct_ranking(np.zeros(6), wrists, eligible, 1, config) == [0]  # ties: the lowest index


def test_shadow_base_is_the_forearm_below_the_palm(hands, kins, retargeters):
    d = hands["shadow"].description
    g = retargeters["shadow"].retarget(box_contact_sets()[0])
    base = pose_to_matrix(g.wrist_pose)
    palm = base @ kins["shadow"].link_poses(torch.as_tensor(g.q)[None], ["palm"])[0, 0].numpy()
    assert kins["shadow"].base_link == "forearm" and d.wrist.link == "palm"
    assert np.linalg.norm(palm[:3, 3] - base[:3, 3]) > 0.2  # forearm origin 0.29 m behind the palm


def test_hand_frames_are_right_handed(retargeters):
    for r in retargeters.values():
        assert r.frame.chirality == 1.0


# -- bad input -----------------------------------------------------------------------------------
def test_nan_and_wrongly_shaped_targets_are_refused(solvers):
    solver = solvers["allegro"]
    bad = torch.zeros(3, 5, 3, dtype=torch.float64)
    bad[1, 2, 0] = float("nan")
    with pytest.raises(ArrayError, match=r"retargeting: targets holds NaN or inf \(at index \[1, 2, 0\]\)"):
        solver.solve(bad)
    with pytest.raises(ArrayError, match=r"targets has shape \(3, 4, 3\), expected \(N, 5, 3\) \(one per slot"):
        solver.solve(torch.zeros(3, 4, 3))
    with pytest.raises(ArrayError, match=r"q_init has shape \(3, 15\), expected \(3, 16\).*'allegro' joint order"):
        solver.solve(torch.zeros(3, 5, 3), q_init=torch.zeros(3, 15))
    with pytest.raises(ArrayError, match="retargeting: q_prev holds NaN or inf"):
        solver.solve(torch.zeros(3, 5, 3), q_prev=torch.full((3, 16), float("nan")))


def test_nan_and_wrongly_shaped_contacts_are_refused():
    with pytest.raises(ArrayError, match=r"contact positions holds NaN or inf \(at index \[0, 0\]"):
        check_contact_array(np.full((5, 3), np.nan))
    with pytest.raises(ArrayError, match=r"contact positions has shape \(4, 3\), expected \(5, 3\)"):
        topology_descriptors(np.zeros((4, 3)))


def test_degenerate_contacts_fail_with_a_reason(retargeters):
    line = np.stack([np.linspace(0, 0.1, 5), np.zeros(5), np.zeros(5)], axis=1)
    with pytest.raises(SynthesisError, match="contact set 0: the contacts are .*collinear") as info:
        topology_descriptors(line)
    assert info.value.reason == "degenerate_contacts"
    same_line = top_grasp()
    same_line[[3, 4]] = same_line[[1, 2]]  # ring/little on index/middle: no lateral spread
    assert contact_problems(same_line[None]) == ["no lateral spread from index/middle to ring/little"]
    good, bad = box_contact_sets()[0], ContactSet(line, np.tile([0.0, 0, 1], (5, 1)))
    out = retargeters["shadow"].retarget_many([good, bad])
    assert isinstance(out[0], Grasp) and isinstance(out[1], SynthesisError)
    assert out[1].reason == "degenerate_contacts" and "contact set 1" in str(out[1])
    with pytest.raises(SynthesisError, match="collinear"):
        retargeters["shadow"].retarget(bad)


def test_wrong_types_and_config_keys_are_refused(retargeters):
    with pytest.raises(TypeError, match="sequence of ContactSet"):
        retargeters["allegro"].retarget_many(box_contact_sets()[0])
    with pytest.raises(TypeError, match="sequence of ContactSet"):
        retargeters["allegro"].retarget_many([np.zeros((5, 3))])
    with pytest.raises(ValueError, match="got no contact sets"):
        retargeters["allegro"].retarget_many([])
    with pytest.raises(ValidationError, match="extra"):
        RetargetConfig(pich_deg=20)


class _SharedJointHand(HandModel):
    """Allegro whose index finger also claims the middle finger's first joint."""

    def __init__(self, hand: HandModel) -> None:
        self._hand = hand
        d = hand.description
        index = dataclasses.replace(d.fingers[0], joints=d.fingers[0].joints + ("joint_4.0",))
        self._d = dataclasses.replace(d, fingers=(index, *d.fingers[1:]))

    @property
    def description(self):
        return self._d

    def urdf_path(self):
        return self._hand.urdf_path()


def test_fingers_sharing_a_joint_are_refused(hands, kins):
    with pytest.raises(AssetError, match="finger 'middle' shares joints with another finger"):
        VectorRetargeter(_SharedJointHand(hands["allegro"]), kinematics=kins["allegro"])


def test_hand_without_left_or_right_is_refused(hands):
    d = hands["allegro"].description
    points = {"knuckles": np.zeros((3, 3)), "middle_tip": np.array([0, 0, 0.1]), "little_tip": np.array([0, 0, 0.1])}
    with pytest.raises(AssetError, match="hand 'allegro': its middle and little-slot fingertips are not side by side"):
        hand_frame(d, points)


def test_one_off_helper_matches_the_reusable_retargeter(hands, retargeters):
    box = box_contact_sets()[1]
    np.testing.assert_allclose(retarget_contacts(hands["shadow"], box).q, retargeters["shadow"].retarget(box).q)


class _NoKeypointsHand(_SharedJointHand):
    """Allegro with no keypoint_links declared."""

    def __init__(self, hand: HandModel) -> None:
        self._hand = hand
        d = hand.description
        self._d = dataclasses.replace(d, fingers=tuple(dataclasses.replace(f, keypoint_links=()) for f in d.fingers))


def test_knuckles_fall_back_to_one_finger_length_behind_the_tips(hands, kins, retargeters):
    estimated = GraspRetargeter(_NoKeypointsHand(hands["allegro"]), kinematics=kins["allegro"]).frame.knuckle_center
    declared = retargeters["allegro"].frame.knuckle_center
    assert np.linalg.norm(estimated - declared) < 0.02, (estimated, declared)


# -- table clearance -------------------------------------------------------------------------------
def test_raise_contacts_lifts_only_low_contacts():
    pos = np.array([[[0.0, 0.0, 0.005], [0.01, 0.0, 0.04], [0.02, 0.0, 0.025], [0.03, 0.0, -0.01], [0.0, 0.0, 0.1]]])
    before = pos.copy()
    out = raise_contacts(pos, 0.025)
    np.testing.assert_array_equal(pos, before)  # input untouched
    np.testing.assert_allclose(out[0, :, 2], [0.025, 0.04, 0.025, 0.025, 0.1])
    np.testing.assert_array_equal(out[..., :2], pos[..., :2])
    np.testing.assert_array_equal(raise_contacts(np.abs(pos), 0.0), np.abs(pos))  # 0: nothing above the table moves


@pytest.mark.parametrize("name", HANDS)
def test_low_contacts_put_the_fingertips_at_the_clearance_height(hands, kins, name):
    """A top-down grasp of a 1 cm-high slab: with the clearance the fingertips (by FK, an independent
    check of the solve) sit near 25 mm, without it near the 10 mm contacts (the wrist search's table
    penalty off: it would lift the 12 mm Allegro fingertip spheres off the table, the job of the clearance)."""
    d = hands[name].description
    contacts = ContactSet(top_grasp(0.03, 0.025, height=0.01), np.array([[-1.0, 0, 0]] + [[1.0, 0, 0]] * 4), "slab")
    heights = {}
    for floor in (0.0, 0.025):
        config = RetargetConfig(min_contact_height=floor, wrist_search={"table_weight": 0.0})
        g = GraspRetargeter(hands[name], config, kinematics=kins[name]).retarget(contacts)
        np.testing.assert_allclose(np.asarray(g.meta["aimed_contacts"])[:, 2], max(floor, 0.01))
        base = pose_to_matrix(g.wrist_pose)
        tips = kins[name].points(torch.as_tensor(g.q)[None], list(d.tip_links), [f.tip_offset for f in d.fingers])
        heights[floor] = np.median(tips[0].numpy() @ base[2, :3] + base[2, 3])
    assert abs(heights[0.0] - 0.01) < 0.005 and abs(heights[0.025] - 0.025) < 0.005, heights


def test_negative_clearance_is_refused():
    with pytest.raises(ValidationError, match="min_contact_height"):
        RetargetConfig(min_contact_height=-0.01)


def lowest_hand_point(hand: HandModel, kin: HandKinematics, grasp: Grasp) -> float:
    """Lowest collision-geometry point of the hand at the grasp, object frame, m (independent FK composition)."""
    points = collision_points(hand.urdf_text())
    poses = pose_to_matrix(grasp.wrist_pose) @ kin.link_poses(torch.as_tensor(grasp.q)[None], list(points))[0].numpy()
    return min(
        float((pose[:3, :3] @ p.T + pose[:3, 3:])[2].min()) for pose, p in zip(poses, points.values(), strict=True)
    )


@pytest.mark.parametrize("name", HANDS)
def test_table_penalty_steers_the_wrist_search_away_from_the_table(hands, kins, name):
    """Asking for a 10 cm clearance must raise the hand's lowest point above where the fit alone puts it."""
    contacts = box_contact_sets()[0]
    lowest = {}
    for clearance, weight in ((0.0, 0.0), (0.1, 10.0)):
        search = {"table_clearance": clearance, "table_weight": weight}
        r = GraspRetargeter(hands[name], RetargetConfig(wrist_search=search), kinematics=kins[name])
        lowest[clearance] = lowest_hand_point(hands[name], kins[name], r.retarget(contacts))
    assert lowest[0.1] > lowest[0.0] + 0.005, lowest


def sphere_cloud(radius: float, n: int = 2000) -> ObjectCloud:
    rng = np.random.default_rng(3)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return ObjectCloud(points=radius * normals, normals=normals)


def test_object_penalty_counts_depth_inside_the_surface_only():
    """Against a sphere's exact signed distance: points outside cost nothing, inside cost weight * depth^2."""
    config = WristSearchConfig(object_clearance=0.0, object_weight=10.0, cloud_points=2000)
    cloud = sphere_cloud(0.05)
    directions = np.random.default_rng(4).normal(size=(3, 6, 3))
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    radii = np.array([0.07, 0.045, 0.04])[:, None, None]  # outside, 5 mm deep, 10 mm deep
    penalty = object_penalty(directions * radii, cloud, config)
    exact = 10.0 * 6 * np.clip(0.05 - radii[:, 0, 0], 0, None) ** 2
    assert penalty[0] == 0.0
    np.testing.assert_allclose(penalty[1:], exact[1:], rtol=0.15)  # nearest-sample approximation


def test_object_penalty_ignores_points_beside_an_object_near_its_bottom():
    """Points beside a box just above the table are outside it (exact depth 0): they must cost nothing.

    Their nearest surface sample can be on the bottom face (outward normal -z), which reads a point
    above the table as inside (the nearest-sample approximation's false positive)."""
    config = WristSearchConfig(object_clearance=0.0, object_weight=10.0, cloud_points=1024)
    half, center = np.array([0.03, 0.05, 0.035]), np.array([0.0, 0.0, 0.035])
    mesh = trimesh.creation.box(extents=2 * half)
    mesh.apply_translation(center)
    cloud = ObjectCloud(*sample_surface(mesh, 1024, seed=0))
    rng = np.random.default_rng(5)
    beside = np.column_stack(
        [rng.uniform(half[0] + 0.012, half[0] + 0.03, 200), rng.uniform(-0.04, 0.04, 200), rng.uniform(0, 0.002, 200)]
    )
    inside = center + rng.uniform(-0.6, 0.6, (200, 3)) * half
    assert np.all(box_depth(beside, half, center) == 0.0) and np.all(box_depth(inside, half, center) > 0.0)
    assert np.all(object_penalty(beside[:, None], cloud, config) == 0.0)
    assert np.all(object_penalty(inside[:, None], cloud, config) > 0.0)


def box_depth(points: np.ndarray, half: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Exact depth inside an axis-aligned box (0 outside), metres."""
    inside = half - np.abs(points - center)
    return np.clip(inside.min(axis=-1), 0.0, None)


def test_object_cloud_keeps_the_hand_body_out_of_the_object(hands, kins):
    """Contacts 2 cm below a box's top: without the box's surface samples the Shadow's middle phalanges go
    over its top edge into it; with them they come out (exact box depth). (The Allegro's body stays out of
    this box either way, 2e-7 m^2, so it cannot show the effect.)"""
    name = "shadow"
    hand, d = hands[name], hands[name].description
    half, center = np.array([0.03, 0.05, 0.035]), np.array([0.0, 0.0, 0.035])
    mesh = trimesh.creation.box(extents=2 * half)
    mesh.apply_translation(center)
    cloud = ObjectCloud(*sample_surface(mesh, 1024, seed=0))
    contacts = ContactSet(top_grasp(0.03, 0.025, height=0.05), np.array([[-1.0, 0, 0]] + [[1.0, 0, 0]] * 4), "box")
    points = collision_points(hand.urdf_text())
    body = [link for link in points if link not in set(d.tip_links)]
    depth = {}
    for with_cloud in (False, True):
        r = GraspRetargeter(hand, kinematics=kins[name])
        g = r.retarget_many([contacts], [cloud] if with_cloud else None)[0]
        poses = pose_to_matrix(g.wrist_pose) @ kins[name].link_poses(torch.as_tensor(g.q)[None], body)[0].numpy()
        inside = [
            box_depth((pose[:3, :3] @ points[link].T + pose[:3, 3:]).T, half, center)
            for pose, link in zip(poses, body, strict=True)
        ]
        depth[with_cloud] = float(sum((x**2).sum() for x in inside))
    print(f"{name}: body depth^2 sum without cloud {depth[False]:.2e}, with {depth[True]:.2e}")
    assert depth[False] > 1e-5 and depth[True] < 0.5 * depth[False], depth

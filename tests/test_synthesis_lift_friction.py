"""lift_friction_bound: checked against the cone's slope and against a linear program over the contact forces;
lift_capacity and held_weight against closed forms of simple pinches."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.optimize import linprog

from ges_core.errors import ArrayError
from ges_core.synthesis.contacts.lift_friction import held_weight, lift_capacity, lift_friction_bound

MIN_HEIGHT = 0.01


def _cloud(mesh: trimesh.Trimesh, n: int = 3000) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) surface samples of ``mesh`` resting on z = 0, and their face normals."""
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    points, faces = trimesh.sample.sample_surface(mesh, n, seed=0)
    return points, mesh.face_normals[faces]


def _upright_cone(radius: float, height: float) -> tuple[np.ndarray, np.ndarray]:
    return _cloud(trimesh.creation.cone(radius, height, sections=64))


def _can_push_up(points: np.ndarray, normals: np.ndarray, mu: float, edges: int = 16) -> bool:
    """Whether contact forces inside friction pyramids (``edges`` edges, inscribed in the cone of ``mu``) at the
    samples above MIN_HEIGHT can add up to a unit upward force: force balance only, scipy's LP."""
    columns = []
    for p, n in zip(points, normals, strict=True):
        if p[2] < MIN_HEIGHT:
            continue
        t1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(n, t1)
        for k in range(edges):
            a = 2 * math.pi * k / edges
            columns.append(-n + mu * (math.cos(a) * t1 + math.sin(a) * t2))
    result = linprog(np.zeros(len(columns)), A_eq=np.array(columns).T, b_eq=[0.0, 0.0, 1.0], bounds=(0, None))
    return result.status == 0


@pytest.mark.parametrize(("radius", "height"), [(0.05, 0.07), (0.04, 0.10)])
def test_an_upright_cone_needs_the_friction_of_its_slope(radius, height):
    """The sides of an upright cone face up at atan(r / h) from the horizontal (r: the 64-gon's inradius) and no
    contact there pushes up below mu = r / h (the bound); the LP over the samples agrees on both sides of it."""
    points, normals = _upright_cone(radius, height)
    bound = lift_friction_bound(points, normals, MIN_HEIGHT)
    assert bound == pytest.approx(radius * math.cos(math.pi / 64) / height, rel=1e-9)
    assert not _can_push_up(points[::10], normals[::10], 0.95 * bound)
    assert _can_push_up(points[::10], normals[::10], 1.15 * bound)


def test_a_face_that_is_not_tilted_up_needs_no_friction_at_all():
    assert lift_friction_bound(*_cloud(trimesh.creation.box([0.05, 0.05, 0.08])), MIN_HEIGHT) == 0.0
    upside_down = trimesh.creation.cone(0.05, 0.07, sections=64)
    upside_down.apply_transform(trimesh.transformations.rotation_matrix(math.pi, [1.0, 0.0, 0.0]))
    assert lift_friction_bound(*_cloud(upside_down), MIN_HEIGHT) == 0.0  # its sides face down


def test_only_the_surface_above_min_height_counts():
    """The cone's base faces straight down but lies on the table: it does not lower the bound; a cloud wholly
    below min_height has nothing to touch (inf)."""
    points, normals = _upright_cone(0.05, 0.07)
    assert (normals[points[:, 2] < MIN_HEIGHT, 2] < -0.99).any()  # the base is sampled
    assert lift_friction_bound(points, normals, 0.0) == 0.0
    assert lift_friction_bound(points, normals, 1.0) == math.inf


def test_bad_clouds_are_refused():
    with pytest.raises(ArrayError, match="normals"):
        lift_friction_bound(np.zeros((4, 3)), np.zeros((3, 3)), MIN_HEIGHT)
    with pytest.raises(ArrayError, match="points"):
        lift_friction_bound(np.full((4, 3), np.nan), np.ones((4, 3)), MIN_HEIGHT)


# --- lift_capacity: weight held per unit total normal force, by a linear program ---------------------------------

CENTER = np.array([0.0, 0.0, 0.05])


def _pair(tilt_deg: float, dy: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A thumb at +x and four fingers at -x (stacked in y about ``dy``), at the centre's height, their outward
    normals turned ``tilt_deg`` up from horizontal (a roof: the squeeze pushes the object down when positive)."""
    c, s = math.cos(math.radians(tilt_deg)), math.sin(math.radians(tilt_deg))
    positions = np.array([[0.03, dy, 0.05], *[[-0.03, dy + y, 0.05] for y in (-0.015, -0.005, 0.005, 0.015)]])
    normals = np.array([[c, 0.0, s], *[[-c, 0.0, s]] * 4])
    return positions, normals


@pytest.mark.parametrize("tilt", [-20.0, 0.0, 10.0, 20.0])
def test_the_capacity_of_a_tilted_squeeze_is_the_friction_left_after_the_slope(tilt):
    # per unit normal force a contact on a face tilted up by t gives at most mu cos t - sin t upward (the cone's
    # steepest edge), so the best split of a unit normal budget holds that much weight; 64 edges ~ the round cone
    positions, normals = _pair(tilt)
    got = lift_capacity(positions, normals, 0.5, CENTER, radius=0.05, cone_edges=64)
    t = math.radians(tilt)
    assert got == pytest.approx(max(0.0, 0.5 * math.cos(t) - math.sin(t)), rel=2e-3, abs=1e-9)


def test_a_slope_steeper_than_the_friction_holds_nothing_and_more_friction_helps():
    positions, normals = _pair(31.0)  # tan 31 deg = 0.60 > 0.5
    assert lift_capacity(positions, normals, 0.5, CENTER, radius=0.05) == 0.0
    assert lift_capacity(positions, normals, 1.0, CENTER, radius=0.05) > 0.3


def test_weight_off_the_contacts_needs_torque_and_costs_capacity():
    # the centre of mass 4 cm beside the contact rows: the contacts must also balance the weight's torque
    near = lift_capacity(*_pair(0.0), 0.5, CENTER, radius=0.05)
    far = lift_capacity(*_pair(0.0, dy=0.04), 0.5, CENTER, radius=0.05)
    assert 0.0 <= far < near


# --- held_weight: the weight held with every joint's torque within its limit ---------------------------------------


def _pinch(lever: float, rise: float = 0.0):
    """A thumb at +x and two fingers at -x (y = +-1 cm), horizontal outward normals, at the centre's height. Each
    contact moves with its own joint 0 / 1 / 2: pushing it inward by 1 m costs ``lever`` rad, lifting it ``rise``
    (the Jacobian column (-lever, 0, rise) at +x, mirrored at -x), so a contact pushing N inward and T up loads its
    joint with ``lever N + rise T``."""
    positions = np.array([[0.03, 0.0, 0.05], [-0.03, -0.01, 0.05], [-0.03, 0.01, 0.05]])
    normals = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    jac = np.zeros((3, 3, 3))
    jac[0, :, 0] = [-lever, 0.0, rise]
    jac[1, :, 1] = [lever, 0.0, rise]
    jac[2, :, 2] = [lever, 0.0, rise]
    return positions, normals, jac


@pytest.mark.parametrize("rise", [0.0, 0.05])
def test_a_pinch_holds_what_its_weakest_side_can_squeeze(rise):
    # thumb limited to tau: N_thumb (lever + rise mu) <= tau at full friction; the fingers (2 joints) are stronger
    # than the thumb together, so the thumb's side binds: W = 2 mu N_thumb = 2 mu tau / (lever + rise mu)
    positions, normals, jac = _pinch(0.1, rise)
    tau, mu = 0.5, 0.5
    got = held_weight(positions, normals, mu, CENTER, jac, [[0], [1], [2]], np.full(3, tau), cone_edges=64)
    assert got == pytest.approx(2 * mu * tau / (0.1 + rise * mu), rel=3e-3)


def test_fingers_on_one_joint_share_its_torque():
    # a thumb twice as strong: with a joint per finger each finger gives tau/lever, the pair matches the thumb and the
    # grasp holds twice a single finger's share; on one shared joint the pair gives tau/lever in all: half that
    positions, normals, jac = _pinch(0.1)
    strong_thumb = np.array([1.0, 0.5, 0.5])
    apart = held_weight(positions, normals, 0.5, CENTER, jac, [[0], [1], [2]], strong_thumb, cone_edges=64)
    jac_shared = jac.copy()
    jac_shared[2, :, 1], jac_shared[2, :, 2] = jac[2, :, 2], 0.0
    shared = held_weight(positions, normals, 0.5, CENTER, jac_shared, [[0], [1], [1]], strong_thumb, cone_edges=64)
    assert apart == pytest.approx(2 * 0.5 * 1.0 / 0.1, rel=3e-3)
    assert shared == pytest.approx(apart / 2, rel=3e-3)


def test_held_weight_scales_with_the_limits_and_needs_both_sides():
    positions, normals, jac = _pinch(0.1)
    joints = [[0], [1], [2]]
    one = held_weight(positions, normals, 0.5, CENTER, jac, joints, np.full(3, 0.5))
    assert held_weight(positions, normals, 0.5, CENTER, jac, joints, np.full(3, 1.5)) == pytest.approx(3 * one)
    assert held_weight(positions[1:], normals[1:], 0.5, CENTER, jac[1:], joints[1:], np.full(3, 0.5)) == 0.0
    # weight off the contacts costs capacity, as for lift_capacity
    assert held_weight(positions, normals, 0.5, CENTER + [0.0, 0.03, 0.0], jac, joints, np.full(3, 0.5)) < one


def test_contacts_no_joint_moves_are_unbounded_and_bad_input_is_named():
    positions, normals, jac = _pinch(0.1)
    assert held_weight(positions, normals, 0.5, CENTER, jac, [[], [], []], np.full(3, 0.5)) == math.inf
    with pytest.raises(ArrayError, match="2 joint lists for 3 contacts"):
        held_weight(positions, normals, 0.5, CENTER, jac, [[0], [1]], np.full(3, 0.5))
    with pytest.raises(ArrayError, match="jacobians"):
        held_weight(positions, normals, 0.5, CENTER, jac[:2], [[0], [1], [2]], np.full(3, 0.5))
    with pytest.raises(ArrayError, match="effort"):
        held_weight(positions, normals, 0.5, CENTER, jac, [[0], [1], [2]], np.full(3, np.nan))

"""Ferrari-Canny epsilon: cases with known answers, invariances, and an LP cross-check of the hull."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError
from scipy.optimize import linprog
from scipy.spatial import ConvexHull

from ges_core.errors import ArrayError
from ges_core.synthesis.contacts.force_closure import (
    ForceClosureConfig,
    cone_forces,
    ferrari_canny,
    primitive_wrenches,
    wrench_space_epsilon,
)

ORIGIN = np.zeros(3)


def equator(n: int, radius: float = 1.0, phase: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """n contacts evenly spaced on a sphere's equator: positions (n, 3) and outward normals (n, 3)."""
    a = phase + 2 * np.pi * np.arange(n) / n
    nrm = np.column_stack([np.cos(a), np.sin(a), np.zeros(n)])
    return radius * nrm, nrm


def cube_faces(half: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """One contact at the centre of each face of a cube."""
    nrm = np.vstack([np.eye(3), -np.eye(3)])
    return half * nrm, nrm


def in_hull(wrenches: np.ndarray, x: np.ndarray) -> bool:
    """Is ``x`` a convex combination of the rows of ``wrenches``? (LP feasibility, independent of qhull)."""
    m = len(wrenches)
    a_eq = np.vstack([wrenches.T, np.ones((1, m))])
    res = linprog(np.zeros(m), A_eq=a_eq, b_eq=np.r_[x, 1.0], bounds=(0, None), method="highs")
    return res.status == 0


def test_three_contacts_120_degrees_apart_on_an_equator_are_in_force_closure():
    pos, nrm = equator(3)
    assert ferrari_canny(pos, nrm, center=ORIGIN) > 0.05


def test_contacts_all_on_one_face_have_no_force_closure():
    pos = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0], [0.0, 0.3, 1.0], [0.2, 0.25, 1.0], [-0.2, 0.1, 1.0]])
    nrm = np.tile([0.0, 0.0, 1.0], (5, 1))
    assert ferrari_canny(pos, nrm, ForceClosureConfig(mu=1.0), center=ORIGIN) == 0.0


@pytest.mark.parametrize("mu", [0.3, 1.0, 3.0])
def test_two_antipodal_point_contacts_cannot_resist_torsion_about_their_axis(mu):
    pos = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]])
    assert ferrari_canny(pos, pos, ForceClosureConfig(mu=mu, cone_edges=16), center=ORIGIN) == 0.0


def test_frictionless_contacts_never_close_with_three_fingers():
    pos, nrm = equator(3)
    assert ferrari_canny(pos, nrm, ForceClosureConfig(mu=0.0), center=ORIGIN) == 0.0


def test_six_face_centres_of_a_cube_beat_a_marginal_grasp():
    good = ferrari_canny(*cube_faces(), center=ORIGIN, radius=0.5)
    # two nearly coincident antipodal pairs: torsion about their axis is resisted only through a 2 cm lever
    pos = np.array([[0.5, 0.02, 0.0], [-0.5, 0.02, 0.0], [0.5, -0.02, 0.0], [-0.5, -0.02, 0.0]])
    marginal = ferrari_canny(pos, np.sign(pos[:, :1]) * [1.0, 0.0, 0.0], center=ORIGIN, radius=0.5)
    assert 0.0 < marginal < 0.1 * good


def test_epsilon_is_invariant_to_translating_object_and_contacts():
    pos, nrm = equator(5, radius=0.04, phase=0.3)
    pos[:, 2] += 0.01 * np.arange(5) - 0.02
    shift = np.array([0.7, -1.3, 2.9])
    for center in (ORIGIN, None):
        moved_center = None if center is None else center + shift
        a = ferrari_canny(pos, nrm, center=center)
        b = ferrari_canny(pos + shift, nrm, center=moved_center)
        assert a > 0 and b == pytest.approx(a, rel=1e-9)


def test_epsilon_is_invariant_to_scale_with_the_default_torque_scale():
    pos, nrm = equator(4, radius=0.03, phase=0.1)
    pos[:, 2] += [0.01, -0.01, 0.005, 0.0]
    assert ferrari_canny(10 * pos, nrm, center=ORIGIN) == pytest.approx(ferrari_canny(pos, nrm, center=ORIGIN))


def test_explicit_torque_scale_equals_one_over_radius():
    pos, nrm = equator(3, radius=0.05)
    by_radius = ferrari_canny(pos, nrm, center=ORIGIN, radius=0.2)
    by_scale = ferrari_canny(pos, nrm, ForceClosureConfig(torque_scale=5.0), center=ORIGIN)
    assert by_scale == pytest.approx(by_radius)


def test_epsilon_increases_with_friction():
    pos, nrm = equator(3)
    eps = [ferrari_canny(pos, nrm, ForceClosureConfig(mu=mu), center=ORIGIN) for mu in (0.1, 0.2, 0.4, 0.8)]
    assert all(b > a for a, b in zip(eps, eps[1:], strict=False))


def test_epsilon_is_the_inradius_of_the_wrench_hull():
    """Points at 0.98 eps in random directions lie in the hull, a point at 1.02 eps along the closest
    facet's normal does not (LP membership, not qhull), and no direction's support is below eps."""
    pos, nrm = equator(5, radius=0.04, phase=0.2)
    pos[:, 2] += [0.01, -0.01, 0.0, 0.005, -0.005]
    w = primitive_wrenches(pos, nrm, center=ORIGIN)
    eps = wrench_space_epsilon(w)
    dirs = np.random.default_rng(0).normal(size=(40, 6))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert all(in_hull(w, 0.98 * eps * d) for d in dirs)
    assert (w @ dirs.T).max(axis=0).min() >= eps * (1 - 1e-9)
    eq = ConvexHull(w).equations
    closest = eq[np.argmax(eq[:, -1]), :-1]
    assert not in_hull(w, 1.02 * eps * closest)


def test_cone_edges_have_unit_normal_part_and_mu_tangential_part():
    _, nrm = equator(4, phase=0.4)
    nrm = np.vstack([nrm, [[0.0, 0.0, 1.0], [0.6, 0.0, -0.8]]])
    f = cone_forces(nrm, 0.7, 8)
    normal_part = np.einsum("nej,nj->ne", f, nrm)
    assert np.allclose(normal_part, -1.0)
    tangential = f + nrm[:, None, :]
    assert np.allclose(np.linalg.norm(tangential, axis=2), 0.7)
    assert np.allclose(tangential.sum(axis=1), 0.0, atol=1e-12)  # symmetric edges: -n is the cone's axis


def test_too_few_or_flat_wrenches_give_zero():
    assert wrench_space_epsilon(np.eye(6)) == 0.0  # 6 points span no 6-D interior around the origin
    flat = np.random.default_rng(1).normal(size=(30, 6))
    flat[:, 5] = 0.0
    assert wrench_space_epsilon(flat) == 0.0


def test_config_defaults_and_validation():
    cfg = ForceClosureConfig()
    assert (cfg.mu, cfg.cone_edges, cfg.torque_scale) == (0.5, 8, None)
    for bad in ({"mu": -0.1}, {"cone_edges": 2}, {"torque_scale": 0.0}, {"friction": 0.5}):
        with pytest.raises(ValidationError):
            ForceClosureConfig(**bad)


@pytest.mark.parametrize(
    ("pos", "nrm", "needle"),
    [
        (np.zeros((2, 2)), np.zeros((2, 2)), "contact positions has shape (2, 2), expected (N, 3)"),
        (np.zeros((0, 3)), np.zeros((0, 3)), "give at least one contact"),
        (np.zeros((2, 3)), np.ones((3, 3)), "contact normals has shape (3, 3), expected (2, 3)"),
        (np.full((2, 3), np.nan), np.ones((2, 3)), "contact positions holds NaN or inf"),
        (np.zeros((2, 3)), np.zeros((2, 3)), "give at least one contact, each with a non-zero outward normal"),
    ],
)
def test_malformed_input_raises_one_array_error(pos, nrm, needle):
    with pytest.raises(ArrayError) as err:
        ferrari_canny(pos, nrm)
    assert f"ferrari_canny: {needle}" in str(err.value)

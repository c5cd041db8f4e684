"""The joint solver iterates only the grasps with a finger still moving (its active set of rows)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.kinematics import HandKinematics
from ges_core.registry import load_registry
from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter


@pytest.fixture(scope="module")
def allegro():
    hand = load_registry().build_hand("allegro")
    return hand, HandKinematics.from_hand(hand)


def mixed_targets(hand, solver: VectorRetargeter) -> torch.Tensor:
    """(8, 5, 3): rows 0-3 reachable (fingertips of random joint values: they settle within tolerance), rows 4-7
    out of reach (the same pushed 20 cm out: they never settle)."""
    lim = hand.description.limits_array
    q = np.random.default_rng(5).uniform(lim[:, 0], lim[:, 1], size=(4, len(lim)))
    reach = solver.fingertips(torch.as_tensor(q))
    return torch.cat([reach, reach + torch.tensor([0.2, 0.0, 0.0], dtype=reach.dtype)])


class CountingKinematics:
    """The real HandKinematics, recording the batch size of each Jacobian pass."""

    def __init__(self, kin: HandKinematics) -> None:
        self.kin, self.rows = kin, []

    def __getattr__(self, name):
        return getattr(self.kin, name)

    def points_and_jacobians(self, q, links, offsets):
        self.rows.append(len(q))
        return self.kin.points_and_jacobians(q, links, offsets)


def test_settled_grasps_leave_the_batch_and_results_equal_solving_each_alone(allegro):
    hand, kin = allegro
    counting = CountingKinematics(kin)
    config = VectorRetargetConfig(iterations=20)
    solver = VectorRetargeter(hand, config, kinematics=counting)
    targets = mixed_targets(hand, solver)
    q, residual = solver.solve(targets)
    assert counting.rows[0] == 8 and 4 <= counting.rows[-1] < 8  # reachable rows settled and left; the others not
    assert sum(counting.rows) < 8 * len(counting.rows)
    alone = VectorRetargeter(hand, config, kinematics=kin)
    for i in range(8):
        q_i, residual_i = alone.solve(targets[i : i + 1])
        assert torch.equal(q[i : i + 1], q_i) and torch.equal(residual[i : i + 1], residual_i)
    assert residual[4:].min() > 0.05


def test_with_contact_normals_every_grasp_iterates_to_the_end(allegro):
    """The pad term has no exact solution to settle at: every row runs all iterations (as before the active set)."""
    hand, kin = allegro
    counting = CountingKinematics(kin)
    solver = VectorRetargeter(hand, VectorRetargetConfig(iterations=4), kinematics=counting)
    targets = mixed_targets(hand, solver)
    normals = torch.tensor([0.0, 0.0, 1.0], dtype=targets.dtype).expand(targets.shape).clone()
    solver.solve(targets, normals=normals)
    assert counting.rows == [8] * 5  # the start and four iterations, all rows each time

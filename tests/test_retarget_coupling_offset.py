"""The retargeting solver keeps mimic offsets: ``q_follower = ratio * q_leader + offset`` (the Ability hand's
q2 = 1.0585 q1 + 0.7235 rad). Targets are the fingertips of random coupled configurations of the real hand
(mani-skill's URDF with the package's description); the solver must find configurations that are coupled
with the offset and put every tip back within a millimetre. Dropping the offset leaves each finger's q2
0.72 rad off, centimetres from its target."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import REPO

mani_skill = pytest.importorskip("mani_skill")

from ges_core.hand_files import FileHand  # noqa: E402
from ges_core.synthesis.retarget.solver import VectorRetargetConfig, VectorRetargeter  # noqa: E402

YAML = REPO / "examples" / "ges-ability-hand" / "ges_ability_hand" / "ability.yaml"
URDF = Path(mani_skill.__file__).parent / "assets" / "robots" / "ability_hand" / "ability_hand_right.urdf"


@pytest.fixture(scope="module")
def hand() -> FileHand:
    return FileHand(YAML, URDF)


def test_couplings_carry_the_urdf_offsets(hand):
    offsets = {c.follower: (c.leader, c.ratio, c.offset) for c in hand.description.couplings}
    assert offsets["index_q2"][0] == "index_q1"
    assert offsets["index_q2"][1:] == pytest.approx((1.05851325, 0.72349796))


def test_solver_reaches_coupled_targets_with_offsets(hand):
    d = hand.description
    solver = VectorRetargeter(hand, VectorRetargetConfig(pad_weight=0.0, iterations=20, seeds=256))
    rng = np.random.default_rng(3)
    lim = d.limits_array
    # leaders well inside their limits, so that every follower stays inside its own (no clipping)
    q_true = d.apply_couplings(
        rng.uniform(lim[:, 0] + 0.2 * np.ptp(lim, 1), lim[:, 1] - 0.4 * np.ptp(lim, 1), (16, len(lim)))
    )
    targets = solver.fingertips(torch.as_tensor(q_true))
    q, residual = solver.solve(targets)
    q = q.numpy()
    for c in d.couplings:
        f, lead = d.joint_index([c.follower, c.leader])
        np.testing.assert_allclose(q[:, f], np.clip(c.ratio * q[:, lead] + c.offset, *lim[f]), atol=1e-9)
    assert float(residual.max()) < 1e-3, residual

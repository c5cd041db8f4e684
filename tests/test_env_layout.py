"""Observation/action layout and rotation helpers of ges_core.env."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from ges_core.env.layout import BLOCK_DOCS, GOAL_BLOCKS, ActionLayout, ObservationLayout
from ges_core.errors import ConfigError
from ges_core.registry import load_registry


def _wxyz(r: Rotation) -> np.ndarray:
    return r.as_quat()[..., [3, 0, 1, 2]]


@pytest.mark.parametrize(("form", "wrist"), [("matrix", 3 + 6), ("rotvec", 3 + 3)])
def test_layout_allegro_blocks_are_contiguous_and_sized(form: str, wrist: int) -> None:
    hand = load_registry().build_hand("allegro").description
    contact = (*hand.tip_links, hand.wrist.link)
    layout = ObservationLayout.for_hand(hand, contact, wrist_rotation=form)
    k, f = hand.num_joints, len(hand.fingers)
    assert (k, f) == (16, 4)
    expected = 2 * k + len(contact) + 6 * f + wrist + 6 + (k + 6) + 3 + 3 + 3 + k
    assert layout.size == expected and layout.sizes()["wrist_pose"] == wrist
    assert list(layout.slices) == list(BLOCK_DOCS)
    ends = [s.stop for s in layout.slices.values()]
    starts = [s.start for s in layout.slices.values()]
    assert starts == [0, *ends[:-1]] and ends[-1] == layout.size
    bare = ObservationLayout.for_hand(hand, contact, goal=False, wrist_rotation=form)
    assert bare.with_goal() == layout


def test_wrist_quat_reads_both_forms_as_scipy_writes_them() -> None:
    """The rotation packed as scipy's matrix columns or rotation vector reads back as scipy's quaternion, near the
    half turn too (where the rotation vector flips to its opposite and the two columns do not move)."""
    turns = Rotation.from_rotvec(np.array([[0, 0, np.pi - 1e-7], [0, 0, -np.pi + 1e-7], [1, 1, 0]]))
    rots = Rotation.concatenate([Rotation.random(200, random_state=3), turns])
    for form in ("matrix", "rotvec"):
        layout = ObservationLayout(3, 2, 1, wrist_rotation=form)
        blocks = {name: torch.zeros(len(rots), size, dtype=torch.float64) for name, size in layout.sizes().items()}
        part = rots.as_matrix()[:, :, :2].transpose(0, 2, 1).reshape(-1, 6) if form == "matrix" else rots.as_rotvec()
        blocks["wrist_pose"] = torch.cat([torch.rand(len(rots), 3, dtype=torch.float64), torch.as_tensor(part)], 1)
        got = layout.wrist_quat(layout.pack(blocks)).numpy()
        angle = (Rotation.from_quat(got, scalar_first=True).inv() * rots).magnitude()
        assert got.dtype == np.float64 and np.all(got[:, 0] >= 0) and angle.max() < 1e-6  # float32 observations
    matrix = ObservationLayout(3, 2, 1)
    bad = torch.zeros(2, matrix.size)
    bad[0, matrix.slices["wrist_pose"]] = torch.tensor([0, 0, 0, 1, 0, 0, 2, 0, 0])  # parallel columns: no rotation
    bad[1, matrix.slices["wrist_pose"]] = torch.tensor([0, 0, 0, 1, 0, 0, 0, float("nan"), 0])
    assert torch.isnan(matrix.wrist_quat(bad)).all()
    with pytest.raises(ConfigError, match="wrist_rotation 'euler' is not one of"):
        ObservationLayout(3, 2, 1, wrist_rotation="euler")


def test_add_goal_puts_the_goal_blocks_where_a_goal_layout_packs_them() -> None:
    full, bare = ObservationLayout(3, 2, 1), ObservationLayout(3, 2, 1, goal=False)
    blocks = {name: torch.rand(4, size, dtype=torch.float64) for name, size in full.sizes().items()}
    goal = torch.cat([blocks[g] for g in GOAL_BLOCKS], dim=1)
    bare_obs = bare.pack({k: v for k, v in blocks.items() if k not in GOAL_BLOCKS})
    assert bare.with_goal() == full and full.with_goal() is full
    assert torch.equal(bare.add_goal(bare_obs, goal), full.pack(blocks))
    with pytest.raises(ConfigError, match="goal-less layout's observations"):
        full.add_goal(full.pack(blocks), goal)  # already has them
    with pytest.raises(ConfigError, match=r"goal \(4, 5\)"):
        bare.add_goal(bare_obs, goal[:, :5])


def test_pack_unpack_roundtrip_and_errors() -> None:
    layout = ObservationLayout(3, 2, 1)
    blocks = {name: torch.rand(4, size, dtype=torch.float64) for name, size in layout.sizes().items()}
    blocks["tip_pos"] = blocks["tip_pos"].reshape(4, 1, 3)
    obs = layout.pack(blocks)
    assert obs.shape == (4, layout.size) and obs.dtype == torch.float32
    assert torch.allclose(layout.unpack(obs, "goal_q"), blocks["goal_q"].float())
    del blocks["q"]
    with pytest.raises(ConfigError, match=r"missing blocks \['q'\]"):
        layout.pack(blocks)
    blocks["q"] = torch.zeros(4, 5)
    with pytest.raises(ConfigError, match="wrong size"):
        layout.pack(blocks)
    with pytest.raises(ConfigError, match="every count must be >= 1"):
        ObservationLayout(3, 0, 1)


def test_pack_np_equals_pack_and_checks_the_total() -> None:
    layout = ObservationLayout(3, 2, 1, goal=False)
    gen = torch.Generator().manual_seed(0)
    blocks = {name: torch.randn(4, size, generator=gen, dtype=torch.float64) for name, size in layout.sizes().items()}
    blocks["contact"] = blocks["contact"] > 0  # bool blocks become 0.0 / 1.0 in both
    packed = layout.pack_np({name: value.numpy() for name, value in blocks.items()})
    assert packed.dtype == np.float32 and torch.equal(torch.from_numpy(packed), layout.pack(blocks))
    blocks["goal_q"] = torch.zeros(4, 3)  # not in a NoGoal layout: ignored
    assert torch.equal(
        torch.from_numpy(layout.pack_np({k: v.numpy() for k, v in blocks.items()})),
        layout.pack({k: v for k, v in blocks.items() if k != "goal_q"}),
    )
    blocks["q"] = torch.zeros(4, 5)
    with pytest.raises(ConfigError, match=r"block sizes \{'q': 5, .* give \d+ floats; expected"):
        layout.pack_np({name: value.numpy() for name, value in blocks.items()})


def test_action_layout_maps_limits() -> None:
    lower, upper = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0])
    act = ActionLayout(lower, upper, max_wrist_step=0.02, max_wrist_turn=0.1)
    a = torch.tensor([[1.0, -1.0, 0.5, 0.0, 0.0, 2.0, -1.0, 1.0]])
    assert act.size == 8
    assert torch.allclose(act.joint_targets(a), torch.tensor([[-1.0, 2.0]]))
    dp, dr = act.wrist_deltas(a)
    assert torch.allclose(dp, torch.tensor([[0.02, -0.02, 0.01]]))
    assert torch.allclose(dr, torch.tensor([[0.0, 0.0, 0.1]]))  # clipped to 1
    q = torch.tensor([[0.25, 1.5]])
    assert torch.allclose(act.joint_targets(torch.cat([torch.zeros(1, 6), act.normalize_joints(q)], 1)), q)


def test_recast_rewrites_only_the_wrist_rotation() -> None:
    """Observations recast from the matrix form to the rotation vector and back: every other block copied bit for bit,
    the rotation the same (float32); a layout differing in anything else is refused."""
    matrix, rotvec = ObservationLayout(3, 2, 1), ObservationLayout(3, 2, 1, wrist_rotation="rotvec")
    assert matrix.with_wrist_rotation("rotvec") == rotvec and matrix.with_wrist_rotation("matrix") is matrix
    rots = Rotation.random(50, random_state=5)
    blocks = {name: torch.randn(50, size, dtype=torch.float64) for name, size in matrix.sizes().items()}
    part = torch.as_tensor(rots.as_matrix()[:, :, :2].transpose(0, 2, 1).reshape(-1, 6))
    blocks["wrist_pose"] = torch.cat([blocks["wrist_pose"][:, :3], part], dim=1)
    obs = matrix.pack(blocks)
    as_rotvec = matrix.recast(obs, rotvec)
    assert as_rotvec.dtype == torch.float32 and as_rotvec.shape == (50, rotvec.size)
    for name in matrix.slices:
        if name != "wrist_pose":
            assert torch.equal(rotvec.unpack(as_rotvec, name), matrix.unpack(obs, name))
    wrist = rotvec.unpack(as_rotvec, "wrist_pose")
    assert torch.equal(wrist[:, :3], matrix.unpack(obs, "wrist_pose")[:, :3])
    np.testing.assert_allclose(
        (Rotation.from_rotvec(wrist[:, 3:].double().numpy()).inv() * rots).magnitude(), 0.0, atol=1e-6
    )
    back = rotvec.recast(as_rotvec, matrix)
    torch.testing.assert_close(back, obs, atol=1e-6, rtol=0)
    assert matrix.recast(obs, matrix) is obs
    with pytest.raises(ConfigError, match="differ in more than the wrist's rotation form"):
        matrix.recast(obs, ObservationLayout(3, 2, 1, goal=False, wrist_rotation="rotvec"))

"""Pre-grasp pose: the grasp backed off along the approach direction with the fingers opened.

The paper (Stage 1, step 4): "shifts g 0.02 m along the approach direction and resets intermediate
joints to produce the pre-grasp pose g_init". Our reading, documented in
``docs/synthesis/refine_validate.md``:

* the base link moves back by ``backoff`` metres against the approach direction (the direction the
  hand travels toward the object): ``t_init = t - backoff * approach``; the rotation is kept;
* "resetting intermediate joints", two ways (``opening``):

  - ``retract`` (default): every finger, thumb included, backs off from its contact along the reverse
    of its press direction (:func:`ges_core.synthesis.physics.squeeze.retract_joints`) until its tip is
    about ``retract`` metres short of the grasp; the closing in validation is then the same motion as the
    squeeze that follows it. Each finger's travel is shortened where it would take the finger's links within
    ``clearance`` of the table at the grasp pose or the backed-off pose
    (:func:`ges_core.synthesis.physics.table_clearance.table_clear_retract`): the stored pre-grasp is where
    Stage 2's reaching goes, so it must not be inside the table;
  - ``open_pose``: every finger joint goes to the hand's open pose, except the thumb's first
    ``thumb_keep`` joints (proximal first: rotation and abduction on both built-in hands), which keep
    the grasp's values so the thumb stays opposed; ``open_fraction`` < 1 opens only part of the way.

  Joints that belong to no finger (the Shadow hand's wrist joints) keep the grasp's values.

A pure function: no simulator.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from ges_core.arrays import checked_array
from ges_core.config import ConfigModel, absent_means
from ges_core.errors import ArrayError
from ges_core.hand import HandDescription, HandModel
from ges_core.synthesis.physics.scene import check_grasp
from ges_core.synthesis.physics.table_clearance import table_clear_retract
from ges_core.synthesis.types import Grasp

__all__ = ["THUMB_KEEP", "PregraspConfig", "open_joint_mask", "opened_joints", "pregrasp"]

# 2: rotation and abduction (both built-in hands), so the opened thumb stays opposed and closes by
# flexion toward its contact. With 1 the Shadow thumb swung in from the index side and landed on the
# box's side face (validated grasps on the 20 demo objects, SAPIEN: Shadow 5 with 2, 0 with 1; Allegro 8, 7).
THUMB_KEEP = 2
"""Proximal thumb joints the opened hand keeps at the grasp's values (default of ``SynthesisConfig.thumb_keep``,
the one setting of the opened hand shared by refinement, the pre-grasp and the wrist search)."""


class PregraspConfig(ConfigModel):
    """How far to back off and which joints to open."""

    backoff: float = Field(0.02, ge=0, description="metres moved back against the approach direction (paper: 0.02)")
    # retract: with the open pose the Shadow's straight thumb (THJ1/THJ0 at 0, rotation and abduction kept)
    # came down onto the top of the object in the approach (27 N on the jenga block before the close), and the
    # grasp never recovered: 7 of the 20 demo objects not_lifted. Retracted, the stored grasps of those 7
    # validated 4 (SAPIEN) and 4 (PyBullet); Allegro unchanged (18/17 of 19). docs/synthesis/refine_validate.md.
    opening: Literal["retract", "open_pose"] = Field(
        "retract", description="how the fingers open: back off from the contacts, or go to the hand's open pose"
    )
    # 0.03 m: well past the refined pose's own mm-scale error and the 1-2 cm the squeeze then presses; 0.05 m
    # validated the same 4 of the 7 Shadow failures as 0.03 m.
    retract: float = Field(0.03, ge=0, description="opening=retract: fingertip travel back from the contact, m")
    open_fraction: float = Field(
        1.0, ge=0, le=1, description="opening=open_pose: fraction of the way from the grasp to the open pose"
    )
    # clearance: 5 mm, as refinement's start_clearance and the wrist search's table_clearance. Without it 54 of the
    # 554 stored pre-grasps of the 280 procedural objects (both hands) put a finger below the table at the grasp
    # pose, where the approach ends, and 13 at the pre-grasp pose itself (docs/synthesis/refine_validate.md,
    # "Pre-grasp").
    clearance: float | None = Field(
        0.005,
        ge=0,
        description="opening=retract: m each retracted finger stays above the table at the pre-grasp and the grasp "
        "pose (null: the full retraction)",
        json_schema_extra=absent_means(None),
    )


def pregrasp(
    hand: HandModel,
    grasp: Grasp,
    approach: np.ndarray,
    config: PregraspConfig | None = None,
    *,
    thumb_keep: int = THUMB_KEEP,
) -> Grasp:
    """The pre-grasp ``g_init`` of ``grasp``, object frame like the grasp.

    approach: (3,) direction the hand moves toward the object, object frame (normalized here).
    thumb_keep: with ``opening="open_pose"``, proximal thumb joints that keep the grasp's values
        (:func:`open_joint_mask`).
    Returns a :class:`Grasp` with the backed-off base pose and the opened joints (couplings applied).
    """
    config = config or PregraspConfig()
    d = hand.description
    check_grasp(d, grasp, "pregrasp")
    direction = _unit(approach)
    pose = np.array(grasp.wrist_pose, dtype=np.float64)
    pose[:3] -= config.backoff * direction
    poses = np.stack([np.asarray(grasp.wrist_pose, dtype=np.float64), pose])  # the approach's two ends
    q_init = opened_joints(hand, grasp.q, config, poses, thumb_keep=thumb_keep)
    meta = {**grasp.meta, "pregrasp_backoff": config.backoff, "approach": direction.tolist()}
    return Grasp(hand=grasp.hand, wrist_pose=pose, q=q_init, meta=meta)


def opened_joints(
    hand: HandModel, q: np.ndarray, config: PregraspConfig, poses: np.ndarray, *, thumb_keep: int = THUMB_KEEP
) -> np.ndarray:
    """(K,) the opened hand of grasp joints ``q`` (K,) as ``config.opening`` says (module docs), couplings applied.

    poses: (P, 7) base poses, object frame, where a retracted finger must clear the table (``config.clearance``).
    """
    d = hand.description
    q = np.asarray(q, dtype=np.float64)
    if config.opening == "retract":
        return table_clear_retract(hand, q, poses, travel=config.retract, clearance=config.clearance)[0]
    mask = open_joint_mask(d, thumb_keep)
    opened = q + config.open_fraction * (np.asarray(d.open_pose) - q)
    return d.apply_couplings(np.where(mask, opened, q))


def open_joint_mask(description: HandDescription, thumb_keep: int) -> np.ndarray:
    """(K,) bool: the joints the pre-grasp opens (finger joints minus the thumb's first ``thumb_keep``)."""
    thumb = description.finger_for_slot("thumb")
    kept = set(thumb.joints[:thumb_keep])
    opened = {j for f in description.fingers for j in f.joints} - kept
    return np.array([name in opened for name in description.joint_names])


def _unit(approach: np.ndarray) -> np.ndarray:
    """``approach`` as a (3,) unit vector, or an ArrayError saying what is wrong with it."""
    v = checked_array(approach, (3,), "pregrasp: approach", layout="a direction in the object frame")
    if np.linalg.norm(v) < 1e-9:
        raise ArrayError("pregrasp: approach is a zero vector; pass ContactResult.approach")
    return v / np.linalg.norm(v)

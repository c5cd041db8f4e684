"""Can this hand grasp this object at all? A size check done before any simulation."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ges_core.contact import FINGER_SLOTS
from ges_core.errors import AssetError
from ges_core.hand import HandModel
from ges_core.objects.asset import ObjectAsset

__all__ = ["check_graspable", "hand_span", "object_min_width"]

SPAN_SAMPLES = 512
"""Random joint configurations searched for the widest thumb-to-finger opening."""


def hand_span(hand: HandModel, *, samples: int = SPAN_SAMPLES, seed: int = 0) -> float:
    """Widest distance (m) between the thumb tip and another fingertip over random joint values."""
    return _span(hand, samples, seed)


@lru_cache(maxsize=16)
def _span(hand: HandModel, samples: int, seed: int) -> float:
    import torch

    from ges_core.kinematics import HandKinematics

    d = hand.description
    lim = d.limits_array
    q = np.random.default_rng(seed).uniform(lim[:, 0], lim[:, 1], size=(samples, d.num_joints))
    q = d.apply_couplings(np.vstack([np.asarray(d.open_pose)[None], q]))
    fingers = [d.finger_for_slot(s) for s in FINGER_SLOTS]
    tips = HandKinematics.from_hand(hand).points(
        torch.as_tensor(q), [f.tip_link for f in fingers], [f.tip_offset for f in fingers]
    )
    gaps = torch.linalg.norm(tips[:, 1:] - tips[:, :1], dim=-1)  # thumb to each other slot
    return float(gaps.max())


def object_min_width(obj: ObjectAsset) -> float:
    """Narrowest width (m) of the object's convex hull."""
    import trimesh

    from ges_core.objects.processing import min_width

    try:
        mesh = trimesh.load(obj.mesh_path, force="mesh")
    except (OSError, ValueError) as exc:
        raise AssetError(f"object '{obj.object_id}': cannot read its mesh {obj.mesh_path}: {exc}") from exc
    return min_width(mesh)


def check_graspable(hand: HandModel, obj: ObjectAsset) -> None:
    """Raise AssetError when even the object's narrowest width exceeds the hand's span."""
    width, span = object_min_width(obj), hand_span(hand)
    if width > span:
        raise AssetError(
            f"object '{obj.object_id}' is {width * 100:.1f} cm across at its narrowest, but hand '{hand.name}' "
            f"opens at most {span * 100:.1f} cm from thumb to fingertip; use a smaller object or scale it down"
        )

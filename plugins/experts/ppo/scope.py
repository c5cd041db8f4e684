"""What a PPO checkpoint was made for, read without building the expert (``ExpertSpec.made_for`` of ``ppo``).

Lets a Stage 2 command take the hand from the checkpoint when ``--hand`` is not given, and refuse a checkpoint made
for another hand before it writes anything (:func:`ges_core.experts.made_for.experts_hand`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ges_core.policy import ExpertScope
from ges_core.training.checkpoint import read_checkpoint


def checkpoint_scope(settings: Mapping[str, Any]) -> ExpertScope | None:
    """The scope stored in ``settings["checkpoint"]``; None without a checkpoint (building the expert then says
    that it needs one). AssetError for a missing or foreign file, as building it would raise."""
    checkpoint = settings.get("checkpoint")
    if not checkpoint:
        return None
    data = read_checkpoint(checkpoint)
    return ExpertScope.from_dict(data["ges"]["made_for"], where=f"checkpoint {checkpoint}")

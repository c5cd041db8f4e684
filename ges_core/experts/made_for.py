"""The hand a Stage 2 evaluation runs, as its experts decide it: a trained expert (a PPO checkpoint) is made for one
hand (``ExpertSpec.made_for``, :meth:`ges_core.registry.Registry.expert_scope`).

Without ``--hand``, ``ges eval-experts`` and ``ges evaluate`` run the hand the given experts were made for, so
``ges train-expert D --preset tiny`` (an Allegro preset) then ``ges eval-experts D --expert ppo:checkpoint=...`` on a
dataset of both hands evaluates the Allegro, not registry.yaml's default hand. With ``--hand``, an expert made for
another hand is refused here, before any file is written, naming both.
"""

from __future__ import annotations

from collections.abc import Sequence

from ges_core.errors import ConfigError
from ges_core.experts.choice import ExpertChoice

__all__ = ["experts_hand"]


def experts_hand(registry, experts: Sequence[ExpertChoice], hand: str | None) -> str | None:
    """``hand`` when given (ConfigError if an expert was made for another one); else the one hand the experts
    made for a hand share (ConfigError naming each when they differ), or None when none is made for a hand."""
    made_for = {}
    for choice in experts:
        scope = registry.expert_scope(choice.name, **choice.settings)
        if scope is not None:
            made_for[choice.label] = scope.hand
    if hand:
        other = {label: h for label, h in made_for.items() if h != hand}
        if other:
            listed = ", ".join(f"'{label}' for '{h}'" for label, h in other.items())
            raise ConfigError(
                f"--hand {hand}: expert(s) made for another hand: {listed}; leave --hand out to run the hand the "
                f"experts were made for, or give experts trained on '{hand}'"
            )
        return hand
    hands = sorted(set(made_for.values()))
    if len(hands) > 1:
        listed = ", ".join(f"'{label}' for '{h}'" for label, h in made_for.items())
        raise ConfigError(f"the experts were made for different hands ({listed}); evaluate each hand's experts apart")
    return hands[0] if hands else None

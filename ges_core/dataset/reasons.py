"""What each Stage 1 failure reason means and what to try, for ``ges synth``'s and ``ges dataset info``'s tables.

A record names its first failed step's reason (docs/synthesis/pipeline.md, "What runs"); these are the one-line
explanations printed under the reason counts. The error message in the record's ``errors`` says more about one
object (docs/dataset.md). ``tests/test_dataset_reasons.py`` checks that every reason the pipeline's code can
record has a line here.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

__all__ = ["REASON_HELP", "TRIAL_HELP", "reason_help", "reason_lines"]

REASON_HELP: dict[str, str] = {
    # contacts
    "bad_input": "the point cloud's arrays have the wrong shape or zero-length normals (a cloud passed in by code)",
    "empty_cloud": "the mesh gave no surface points; check it with `ges objects prepare --objects ID`",
    "nan_in_cloud": "the point cloud holds NaN or inf: the mesh has broken faces; repair it (e.g. trimesh) and retry",
    "degenerate_cloud": "too few points, or the object is flat, a line or a point: nothing to put five fingers on",
    "too_low": "the object is lower than contacts.min_height: fingertips cannot get under or beside it",
    "no_graspable_width": "no slice above contacts.min_height is between contacts.min_width and max_width wide as "
    "the object rests (too wide for a hand's opening, or only thin spikes): rest it another way "
    "(--rest ID=graspable, or as_authored) or scale it",
    "no_contact_surface": "no surface point faces the thumb or a finger from above",
    "no_more_layouts": "contacts.layout_rank asks for a contact layout beyond the object's candidates; lower it",
    "bad_mesh": "the mesh cannot be loaded (empty, flat or broken); `ges objects prepare --objects ID` says why",
    "failed": "synthesis stopped on this object; the record's `errors` say why",
    # retargeting
    "degenerate_contacts": "the five contacts do not span a plane, so no wrist frame follows from them",
    "unreachable": "from none of its ranked wrist placements can the hand put its fingertips on the contacts within "
    "retarget.max_residual (a finger that serves two slots, the Allegro's ring, is measured against their mean; the "
    "object is too large or too small for this hand)",
    # refinement
    "penetration": "the closed hand sinks into the object deeper than refine.max_penetration",
    "table_contact": "the closed hand presses on the table (the placement sits too low; common on thin lying objects)",
    "object_moved": "the object moved or turned more than refine.max_object_shift / max_object_turn while the "
    "fingers closed",
    "few_contacts": "fewer than refine.min_touching fingertips (or no thumb) touch the object after closing",
    "unstable_rest": "the object does not stay put on its own in that engine (it rolls or tips): give it a flatter "
    "base or another resting pose (--rest), or skip the check with -o refine.rest_steps=0",
    "no_collision_model": "a concave mesh without a convex decomposition and library.decompose off: run "
    "`ges objects prepare`",
    "unstable": "the simulator blew up (NaN or exploding state) during this step",
    # validation
    "no_contact": "no fingertip touched the object during the trial",
    "palm_only": "lifted and held, but not by enough fingertips (validate.min_tips, the thumb among them): the palm "
    "or the phalanges carried it",
    "dropped": "lifted, then it slipped out during the 200-step hold",
    "not_lifted": "fingertips touched it but it never rose 0.2 m: the grip is too weak for it, or the fingers closed "
    "past it",
    "not_run": "the step did not run (validate_sims empty, or robust.enabled off)",
}
"""Failure reason -> one line: what it means and, where there is one, what to try."""

_CAPACITY = "`ges dataset capacity DATASET` says whether any closing of those fingertips could hold it"

TRIAL_HELP: tuple[tuple[str, str], ...] = (
    (r"limits", "failed with the drives capped at the hand's actuator limits (effort_limit)"),
    (r"mass_x[0-9.e+-]+", f"failed with the object's mass times that factor; {_CAPACITY}"),
    (r"friction_[0-9.e+-]+", f"failed at that (effective) friction coefficient; {_CAPACITY}"),
    (r"pose_[0-9]+", "failed with the object moved a few mm and degrees from where the grasp expects it"),
)
"""(pattern of a perturbation trial's name, what its failure means): the robust step's reasons
(:func:`ges_core.synthesis.physics.robust.perturbations`)."""


def reason_help(reason: str) -> str | None:
    """The line of ``reason`` (a step's failure reason or a perturbation trial's name); None when unknown."""
    if reason in REASON_HELP:
        return REASON_HELP[reason]
    return next((text for pattern, text in TRIAL_HELP if re.fullmatch(pattern, reason)), None)


def reason_lines(reasons: Iterable[str], indent: str = "  ") -> list[str]:
    """``indent + "reason, reason: what they mean"``: the distinct known ``reasons`` joined where their line is
    the same (``mass_x2, mass_x0.5``), in first-seen order; unknown reasons are left out."""
    by_text: dict[str, list[str]] = {}
    for reason in dict.fromkeys(reasons):
        if (text := reason_help(reason)) is not None:
            by_text.setdefault(text, []).append(reason)
    return [f"{indent}{', '.join(names)}: {text}" for text, names in by_text.items()]

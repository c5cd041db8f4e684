"""``ges hand prepare NAME``: make a hand's files what both engines should load, once, cached.

1. Every mesh in a format other than OBJ/STL is converted to OBJ (:mod:`.meshes`).
2. Each collision mesh is measured: how deep its surface lies below its convex hull
   (:func:`.geometry.hull_gap`), and whether its hull overlaps another link's hull where the meshes
   are apart at the open and closing poses (:func:`.geometry.pair_overlaps`).
3. A mesh whose hull is wrong (gap over :data:`HULL_GAP_TOL`, or in such an overlap) is decomposed
   with CoACD (:mod:`.decompose`), with a progress bar; the parts are cached by the mesh's hash and
   both simulators use them from then on (:func:`.engine_urdf.engine_urdf`).

Nothing is written beside the hand's files; a second run finds everything in the cache.

Before a run, ``ges synth`` and ``ges demo`` decompose the meshes of step 3's first rule themselves
(:func:`decompose_deep_hulls`: hull gaps only, a fraction of a second to measure), and :func:`run_synthesis
<ges_core.synthesis.run.pipeline.run_synthesis>` warns (:class:`UnpreparedHandWarning`) when a hand it runs still has
such a mesh; ``ges hand lint`` names them (check ``hull-gap``). The overlap rule takes seconds of pairwise tests at
four poses, so it is left to this command and to the lint's ``hull-overlap`` check.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from ges_core.hand import HandModel
from ges_core.hand_prep.decompose import cached_link_parts, decompose_link_mesh, decomposition_seconds
from ges_core.hand_prep.geometry import (
    HULL_OVERLAP_TOL,
    PairOverlap,
    engine_link_shapes,
    hand_link_poses,
    hull_gap,
    link_shapes,
    pair_overlaps,
)
from ges_core.hand_prep.meshes import (
    NATIVE_FORMATS,
    converted_mesh,
    converted_mesh_if_cached,
    engine_mesh,
    resolve_mesh_path,
)
from ges_core.urdf import parse_urdf

__all__ = [
    "HULL_GAP_TOL",
    "built_prepared",
    "MeshPlan",
    "PrepareReport",
    "UnpreparedHandWarning",
    "decompose_deep_hulls",
    "format_decomposed",
    "prepare_hand",
    "undecomposed_deep_hulls",
    "warn_undecomposed_hulls",
]

HULL_GAP_TOL = 3e-3
"""m: a collision mesh whose surface lies deeper than this below its hull is decomposed. A fingertip pad is
15-20 mm wide; a contact moved 3 mm is a fifth of it. The Ability hand: palm 17.7 mm, distal phalanx 7.3 mm
(decomposed), wrist plate 2.0 mm and thumb links 0 mm (kept)."""


@dataclass
class MeshPlan:
    """One collision mesh file of the hand and what prepare did with it."""

    path: Path
    """The file the engines load (after OBJ conversion)."""
    links: list[str]
    hull_gap: float
    """m, deepest point of the mesh below its hull."""
    overlaps: list[str] = field(default_factory=list)
    """Links whose hulls overlap this one's where the meshes are apart."""
    parts: int = 0
    seconds: float = 0.0
    """CoACD's run time (from the cache's manifest when it ran before)."""
    cached: bool = False

    @property
    def reason(self) -> str:
        """Why it is decomposed, or '' when it is not."""
        why = []
        if self.hull_gap > HULL_GAP_TOL:
            why.append(f"hull {self.hull_gap * 1000:.1f} mm off the mesh")
        if self.overlaps:
            why.append(f"hull overlaps {', '.join(sorted(set(self.overlaps)))}")
        return "; ".join(why)


@dataclass
class PrepareReport:
    """What ``ges hand prepare`` found and did."""

    hand: str
    converted: list[Path]
    meshes: list[MeshPlan]
    overlaps_before: list[PairOverlap]
    overlaps_after: list[PairOverlap]
    seconds: float

    def format(self) -> str:
        """A table: one row per collision mesh, then the overlaps left."""
        lines = [f"hand '{self.hand}': {len(self.converted)} mesh file(s) converted to OBJ (cached by hash)"]
        lines.append(f"  {'collision mesh':<28}{'links':<34}{'hull gap':>9}{'parts':>7}{'CoACD s':>9}  reason")
        for m in self.meshes:
            links = ", ".join(m.links)
            links = links if len(links) <= 32 else links[:29] + "..."
            parts = str(m.parts) if m.parts else "-"
            secs = (f"{m.seconds:.1f}" + ("*" if m.cached else "")) if m.parts else "-"
            gap = f"{m.hull_gap * 1000:>6.1f} mm"
            lines.append(f"  {m.path.name[:27]:<28}{links:<34}{gap}{parts:>7}{secs:>9}  {m.reason or 'kept'}")
        lines.append(
            f"  hull overlaps beyond the meshes': {len(self.overlaps_before)} before, {len(self.overlaps_after)} after"
        )
        lines += [
            f"    left: {o.link_a} / {o.link_b} ({o.pose} pose): hulls {o.hull_overlap * 1000:.1f} mm into each "
            f"other, meshes {o.mesh_gap * 1000:+.1f} mm apart"
            for o in self.overlaps_after
        ]
        cached = any(m.cached for m in self.meshes)
        note = " (*: parts from the cache; the time is CoACD's when they were made)" if cached else ""
        lines.append(f"  {self.seconds:.1f} s{note}")
        return "\n".join(lines)


def prepare_hand(hand: HandModel, *, progress: bool = True) -> PrepareReport:
    """Convert, measure and decompose ``hand``'s meshes (module docs); returns what was done."""
    start = time.perf_counter()
    text, base_dir = hand.urdf_text(), hand.urdf_path().parent
    converted = _convert_all(text, base_dir)
    shapes = link_shapes(text, base_dir)
    links = sorted(shapes)
    poses = hand_link_poses(hand, links)
    excluded = hand.excluded_link_pairs()
    before = pair_overlaps(shapes, poses, excluded, HULL_OVERLAP_TOL)
    plans = _plan(shapes, before)
    _decompose(plans, progress)
    after = pair_overlaps(engine_link_shapes(text, base_dir), poses, excluded, HULL_OVERLAP_TOL)
    return PrepareReport(hand.name, converted, plans, before, after, time.perf_counter() - start)


class UnpreparedHandWarning(UserWarning):
    """A run is about to collide a hand's collision mesh as one convex hull standing more than
    :data:`HULL_GAP_TOL` off the mesh (:func:`warn_undecomposed_hulls`)."""


def undecomposed_deep_hulls(hand: HandModel) -> list[MeshPlan]:
    """The hand's collision meshes whose hull stands more than :data:`HULL_GAP_TOL` off the mesh and whose CoACD
    parts are not in the cache: both engines would collide each as that one hull.

    Only the hull-gap rule (module docs); writes nothing (a mesh whose OBJ copy is not cached has no parts yet).
    Each plan's ``path`` is the mesh file the URDF names.
    """
    plans = _plan(link_shapes(hand.urdf_text(), hand.urdf_path().parent), [], path=lambda source: source)
    return [p for p in plans if p.hull_gap > HULL_GAP_TOL and not _decomposed(p.path)]


def decompose_deep_hulls(hand: HandModel, *, progress: bool = True) -> list[MeshPlan]:
    """Decompose what :func:`undecomposed_deep_hulls` finds, with a progress bar (what ``ges synth`` and ``ges demo``
    do before a run); the plans done, their ``path`` the file the engines load, with parts and seconds."""
    todo = [replace(p, path=engine_mesh(p.path)) for p in undecomposed_deep_hulls(hand)]
    _decompose(todo, progress)
    return todo


def format_decomposed(hand: str, plans: list[MeshPlan]) -> str:
    """One line saying what :func:`decompose_deep_hulls` did for ``hand`` ('' when nothing)."""
    if not plans:
        return ""
    listed = ", ".join(f"{p.path.name} ({p.hull_gap * 1000:.1f} mm, {p.parts} parts)" for p in plans)
    seconds = sum(p.seconds for p in plans)
    return (
        f"hand '{hand}': {len(plans)} collision mesh(es) stood more than {HULL_GAP_TOL * 1000:.0f} mm inside their "
        f"convex hulls: {listed}; decomposed with CoACD ({seconds:.1f} s; cached for later runs). `ges hand prepare "
        f"{hand}` also checks where link hulls overlap"
    )


def built_prepared(registry, name: str) -> HandModel:
    """Hand ``name`` built by ``registry`` after :func:`decompose_deep_hulls` (its bar shown and its line printed
    only when there is something to decompose): what ``ges synth`` and ``ges demo`` do before a run, for a run that
    meets a dataset's grasps (Stage 2), so that it collides the hand as Stage 1 did instead of warning that the hand
    differs. Measuring costs a fraction of a second when nothing is left to decompose."""
    hand = registry.build_hand(name)
    done = decompose_deep_hulls(hand, progress=True)
    if not done:
        return hand
    print(format_decomposed(name, done), flush=True)
    return registry.build_hand(name)  # its engine URDF now names the parts


def warn_undecomposed_hulls(hands: Mapping[str, HandModel]) -> None:
    """:class:`UnpreparedHandWarning` for each hand of ``hands`` (registry name -> hand) with a mesh
    :func:`undecomposed_deep_hulls` finds."""
    for name, hand in hands.items():
        if found := undecomposed_deep_hulls(hand):
            listed = ", ".join(f"{p.path.name} ({p.hull_gap * 1000:.1f} mm)" for p in found)
            warnings.warn(
                f"hand '{name}': collision mesh(es) {listed} stand more than {HULL_GAP_TOL * 1000:.0f} mm inside "
                f"their convex hulls, and both engines collide each as its hull; run `ges hand prepare {name}` "
                "first (decomposes them with CoACD, cached; `ges synth` and `ges demo` do it themselves)",
                UnpreparedHandWarning,
                stacklevel=3,
            )


def _decomposed(source: Path) -> bool:
    """``source`` (a URDF's mesh file) has CoACD parts in the cache."""
    engine = source if source.suffix in NATIVE_FORMATS else converted_mesh_if_cached(source)
    return engine is not None and cached_link_parts(engine) is not None


def _convert_all(text: str, base_dir: Path) -> list[Path]:
    """Convert every non-OBJ/STL mesh (visuals too: PyBullet loads them); the converted files."""
    out = []
    for mesh in parse_urdf(text).iter("mesh"):
        path = resolve_mesh_path(mesh.get("filename", ""), base_dir)
        if path.suffix not in NATIVE_FORMATS and path not in out:
            converted_mesh(path)
            out.append(path)
    return out


def _plan(shapes, overlaps: list[PairOverlap], path=engine_mesh) -> list[MeshPlan]:
    """One plan per collision mesh file (a file several links use is measured and decomposed once). path: the
    plan's file from the URDF's (default: the one the engines load, converting a ``.glb`` to OBJ)."""
    plans: dict[Path, MeshPlan] = {}
    partner = {}
    for o in overlaps:
        partner.setdefault(o.link_a, []).append(o.link_b)
        partner.setdefault(o.link_b, []).append(o.link_a)
    for link, group in shapes.items():
        for shape in group:
            if shape.source is None:
                continue
            file = path(shape.source)
            if file not in plans:
                plans[file] = MeshPlan(file, [], hull_gap(shape.mesh))
            plans[file].links.append(link)
            if plans[file].hull_gap > HULL_OVERLAP_TOL:  # a convex mesh's hull is the mesh: parts would not help
                plans[file].overlaps += partner.get(link, [])
    return list(plans.values())


def _decompose(plans: list[MeshPlan], progress: bool) -> None:
    from tqdm import tqdm

    todo = [p for p in plans if p.reason]
    for plan in tqdm(todo, desc="CoACD", unit="mesh", disable=not progress or not todo):
        plan.cached = cached_link_parts(plan.path) is not None
        plan.parts = len(decompose_link_mesh(plan.path, name=f"hand mesh {plan.path.name} ({', '.join(plan.links)})"))
        plan.seconds = decomposition_seconds(plan.path)

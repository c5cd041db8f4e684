"""Objects with explicit sizes (no random draw), for checks, tests and benchmarks."""

from __future__ import annotations

from pathlib import Path

from ges_core.objects.asset import ObjectAsset, PrimitiveShape
from ges_core.paths import atomic_write_text, cache_dir

__all__ = ["box_asset"]


def box_asset(
    half_extents: tuple[float, float, float] = (0.03, 0.03, 0.03),
    *,
    object_id: str = "simple/box",
    density: float = 500.0,
    friction: float = 1.0,
) -> ObjectAsset:
    """A box centred on its object frame: one exact box primitive; its OBJ surface is cached by size."""
    hx, hy, hz = half_extents
    return ObjectAsset(
        object_id=object_id,
        category="box",
        mesh_path=_box_mesh(half_extents),
        collision=(PrimitiveShape(kind="box", size=tuple(half_extents)),),
        density=density,
        mass=density * 8 * hx * hy * hz,
        friction=friction,
    )


def _box_mesh(half_extents: tuple[float, float, float]) -> Path:
    import trimesh

    path = cache_dir("simple_objects") / ("box_" + "_".join(f"{h:.5f}" for h in half_extents) + ".obj")
    if not path.is_file():
        atomic_write_text(path, trimesh.creation.box(extents=[2 * h for h in half_extents]).export(file_type="obj"))
    return path

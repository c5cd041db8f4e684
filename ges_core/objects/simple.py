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
    resting: bool = True,
) -> ObjectAsset:
    """A box: one exact box primitive; its OBJ surface is cached by size and frame.

    resting: True puts the bottom face at z = 0 (the library's resting frame); False centres the
    box on its object frame.
    """
    hx, hy, hz = half_extents
    lift = hz if resting else 0.0
    return ObjectAsset(
        object_id=object_id,
        category="box",
        mesh_path=_box_mesh(half_extents, lift),
        collision=(PrimitiveShape(kind="box", size=tuple(half_extents), pose=(0.0, 0.0, lift, 1.0, 0.0, 0.0, 0.0)),),
        density=density,
        mass=density * 8 * hx * hy * hz,
        friction=friction,
    )


def _box_mesh(half_extents: tuple[float, float, float], lift: float) -> Path:
    import trimesh

    name = "box_" + "_".join(f"{h:.5f}" for h in half_extents) + f"_z{lift:.5f}.obj"
    path = cache_dir("simple_objects") / name
    if not path.is_file():
        mesh = trimesh.creation.box(extents=[2 * h for h in half_extents])
        mesh.apply_translation((0.0, 0.0, lift))
        atomic_write_text(path, mesh.export(file_type="obj"))
    return path

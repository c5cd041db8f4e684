"""Object library: procedural shapes, pybullet_data meshes and user folders.

``ObjectLibrary`` and ``LibraryConfig`` load lazily so that importing the asset types stays light.
"""

from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape

__all__ = ["ConvexPart", "LibraryConfig", "ObjectAsset", "ObjectLibrary", "PrimitiveShape"]


def __getattr__(name: str):
    if name in ("ObjectLibrary", "LibraryConfig"):
        from ges_core.objects import library

        return getattr(library, name)
    raise AttributeError(f"module 'ges_core.objects' has no attribute '{name}'")

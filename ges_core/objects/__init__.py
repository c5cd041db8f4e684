"""Object library: procedural shapes, pybullet_data meshes and user folders."""

from ges_core.objects.asset import ConvexPart, ObjectAsset, PrimitiveShape

__all__ = ["ConvexPart", "ObjectAsset", "PrimitiveShape"]

"""Engine-ready hand files made once per process (light: no trimesh, no CoACD; the simulator plugins import it
at module level).

Every simulator backend loads the hand again, and Stage 1 builds a backend per trial. Making the engine's URDF file
(:func:`ges_core.hand_prep.engine_urdf.engine_urdf`'s XML rewriting, which hashes every link mesh to look up its
convex parts, then the plugin's own steps) took 5-18 ms of the 23-36 ms of a backend's hand load. The plugins wrap
the function that writes that file in :func:`engine_file_memo`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

from ges_core.paths import cache_root

__all__ = ["engine_file_memo", "note_parts_written"]

_parts_written = 0
"""Link decompositions this process has written: an engine URDF made before the last one may lack its parts."""


def note_parts_written() -> None:
    """Called by :func:`ges_core.hand_prep.decompose.decompose_link_mesh` when it wrote a decomposition."""
    global _parts_written
    _parts_written += 1


def engine_file_memo(make: Callable[..., Path]) -> Callable[..., Path]:
    """``make`` (a function that writes an engine-ready hand file and returns its path, from hashable arguments:
    the URDF text, its folder, ...) called once per process for each set of arguments.

    The file is made again when the cache folder (``$GES_CACHE_DIR``) changed, when this process has decomposed a
    link mesh since (``ges hand prepare``: the parts go into the file) and when the file is gone. The same
    arguments then give the same file, so what the engines load is unchanged; only the work of making it is saved.
    """

    @functools.lru_cache(maxsize=64)
    def cached(args: tuple, kwargs: tuple, _cache: str, _parts: int) -> Path:
        return make(*args, **dict(kwargs))

    @functools.wraps(make)
    def memo(*args, **kwargs) -> Path:
        key = (args, tuple(sorted(kwargs.items())), str(cache_root()), _parts_written)
        path = cached(*key)
        if not Path(path).is_file():  # removed from the cache since: make it again
            cached.cache_clear()
            path = cached(*key)
        return path

    memo.cache_clear = cached.cache_clear  # type: ignore[attr-defined]
    return memo

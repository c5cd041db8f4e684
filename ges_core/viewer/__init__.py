"""The grasp viewer: ``ges view DATASET`` serves an interactive 3D page of a dataset's records (viser).

>>> viewer = start("runs/demo/dataset", port=8080)   # a running server; viewer.url, viewer.show(object, hand)
>>> viewer.server.stop()

The page shows one record at a time in the object frame: the object on its table, the five contacts with their
normals, the hand at grasp and (fainter) at pre-grasp, and the record's figures; a side panel browses by split,
object and hand and switches between the hands on one object. The drawing is built engine- and browser-free
(:func:`~ges_core.viewer.scene.build_scene`); viser, an optional extra (``pip install 'ges-unigrasp[view]'``),
only sends it. See ``docs/viewer.md``.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from ges_core.errors import BackendUnavailable
from ges_core.viewer.data import ViewerData
from ges_core.viewer.scene import Scene, ViewerConfig, build_scene

if TYPE_CHECKING:
    from ges_core.registry import Registry
    from ges_core.viewer.app import GraspViewer

__all__ = ["Scene", "ViewerConfig", "ViewerData", "build_scene", "require_viser", "serve", "start"]


def require_viser():
    """The ``viser`` module; BackendUnavailable with the pip command when it is not installed."""
    try:
        import viser
    except ImportError as exc:
        raise BackendUnavailable(
            "the grasp viewer needs viser, which is not installed: pip install 'ges-unigrasp[view]' "
            "(or pip install viser)"
        ) from exc
    return viser


def start(
    path: str | Path,
    *,
    host: str = "127.0.0.1",
    port: int = 8080,
    registry: Callable[[], Registry] | None = None,
    config: ViewerConfig | None = None,
    initial: tuple[str, str | None] | None = None,
) -> GraspViewer:
    """Open the dataset at ``path`` and serve it; returns the running :class:`~ges_core.viewer.app.GraspViewer`.

    The dataset is checked before any server starts (AssetError: not a dataset, no records). host/port: where to
    listen (viser takes the next free port when ``port`` is taken; ``viewer.url`` says which). initial: the
    (object id, hand or None for its first hand) shown first (default: the first object, its first hand);
    an unknown one is an UnknownNameError or ConfigError. Stop with ``viewer.server.stop()``.
    """
    viser = require_viser()
    from ges_core.viewer.app import GraspViewer

    data = ViewerData(path, registry)
    if initial is not None:
        initial = _checked_initial(data, *initial)
    server = viser.ViserServer(host=host, port=port, label="GES-UniGrasp viewer", verbose=False)
    try:
        viewer = GraspViewer(data, server, config=config, initial=initial)
    except BaseException:
        server.stop()
        raise
    return viewer


def _checked_initial(data: ViewerData, object_id: str, hand: str | None) -> tuple[str, str]:
    """(object, hand) to show first; hand None: the object's first hand. ConfigError naming what the dataset holds."""
    if object_id not in data.objects():
        from ges_core.errors import UnknownNameError

        raise UnknownNameError("object", object_id, data.objects(), where=f" in dataset {data.root}")
    hands = data.hands(object_id)
    if hand is not None and hand not in hands:
        from ges_core.errors import ConfigError

        raise ConfigError(
            f"dataset {data.root} holds no record of object '{object_id}' with hand '{hand}' "
            f"(its hands: {', '.join(hands)})"
        )
    return object_id, hand or hands[0]


def serve(path: str | Path, *, host: str = "127.0.0.1", port: int = 8080, **kwargs) -> None:
    """:func:`start`, print the URL, and serve until Ctrl-C (then stop the server and return)."""
    t0 = time.perf_counter()
    if threading.current_thread() is threading.main_thread():
        # Ctrl-C must stop it even when the parent left SIGINT ignored (a child inherits SIG_IGN across exec, as
        # under pytest-xdist's workers, where the server never stopped)
        signal.signal(signal.SIGINT, signal.default_int_handler)
    viewer = start(path, host=host, port=port, **kwargs)
    try:  # the URL is printed inside: a Ctrl-C right after it (the page already served) still stops cleanly
        print(
            f"ges view: {len(viewer.data)} records of {viewer.data.root} at {viewer.url} "
            f"(ready in {time.perf_counter() - t0:.1f} s; Ctrl-C to stop)",
            flush=True,
        )
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        print("ges view: stopped", flush=True)
    finally:
        viewer.server.stop()

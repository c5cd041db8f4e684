"""PNG files and contact sheets (Pillow, imported on use).

Pictures are written atomically (temporary file + rename) like every other GES-UniGrasp output.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ges_core.errors import AssetError, BackendUnavailable
from ges_core.paths import atomic_write_bytes

__all__ = ["contact_sheet", "read_png", "write_png"]

_LABEL_HEIGHT = 16
"""Pixels under each tile for its label, frame included (Pillow's default bitmap font is 11 px tall)."""


def _pil():
    try:
        from PIL import Image, ImageDraw
    except ImportError as exc:
        raise BackendUnavailable("writing pictures needs Pillow: pip install pillow") from exc
    return Image, ImageDraw


def write_png(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an (H, W, 3) uint8 image as PNG, atomically; returns the path."""
    image_cls, _ = _pil()
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype != np.uint8:
        raise ValueError(f"write_png needs an (H, W, 3) uint8 array, got shape {arr.shape} dtype {arr.dtype}")
    buf = io.BytesIO()
    image_cls.fromarray(arr, mode="RGB").save(buf, format="PNG")
    return atomic_write_bytes(path, buf.getvalue())


def read_png(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 pixels of an image file; AssetError if it cannot be read."""
    image_cls, _ = _pil()
    try:
        with image_cls.open(path) as image:
            return np.asarray(image.convert("RGB"))
    except OSError as exc:  # missing file, not an image
        raise AssetError(f"cannot read picture {path}: {exc}") from exc


def contact_sheet(
    png_paths: Sequence[str | Path],
    path: str | Path,
    *,
    columns: int = 6,
    labels: Sequence[str] | None = None,
    frame_colors: Sequence[tuple[int, int, int]] | None = None,
    gap: int = 4,
) -> Path:
    """Tile pictures into one PNG, row by row, ``columns`` per row.

    Every tile takes the size of the first picture (others are resized to it). ``labels`` (one per
    picture) are printed under the tiles; ``frame_colors`` (RGB 0-255, one per picture) colour the
    ``gap``-pixel frame around each tile, e.g. green for a successful grasp and red for a failed one.
    """
    if not png_paths:
        raise ValueError("contact_sheet needs at least one picture")
    if columns < 1:
        raise ValueError(f"contact_sheet needs columns >= 1, got {columns}")
    for name, values in (("labels", labels), ("frame_colors", frame_colors)):
        if values is not None and len(values) != len(png_paths):
            raise ValueError(f"contact_sheet got {len(values)} {name} for {len(png_paths)} pictures")
    tiles = [read_png(p) for p in png_paths]
    sheet = _tile(tiles, columns, gap, _LABEL_HEIGHT if labels else 0, frame_colors)
    if labels:
        sheet = _draw_labels(sheet, labels, columns, tiles[0].shape, gap)
    return write_png(path, sheet)


def tile_origin(i: int, columns: int, tile_shape: tuple[int, ...], gap: int, label_height: int = 0) -> tuple[int, int]:
    """(row pixel, column pixel) of the top-left corner of tile ``i`` in a contact sheet."""
    h, w = tile_shape[:2]
    row, col = divmod(i, columns)
    return gap + row * (h + label_height + gap), gap + col * (w + gap)


def _tile(
    tiles: list[np.ndarray],
    columns: int,
    gap: int,
    label_height: int,
    frame_colors: Sequence[tuple[int, int, int]] | None,
) -> np.ndarray:
    h, w = tiles[0].shape[:2]
    cols, rows = min(columns, len(tiles)), math.ceil(len(tiles) / columns)
    sheet = np.full((gap + rows * (h + label_height + gap), gap + cols * (w + gap), 3), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        y, x = tile_origin(i, columns, tiles[0].shape, gap, label_height)
        if frame_colors is not None and gap:
            sheet[y - gap : y + h + gap, x - gap : x + w + gap] = frame_colors[i]
        sheet[y : y + h, x : x + w] = _fit(tile, h, w)
    return sheet


def _fit(tile: np.ndarray, h: int, w: int) -> np.ndarray:
    if tile.shape[:2] == (h, w):
        return tile
    image_cls, _ = _pil()
    return np.asarray(image_cls.fromarray(tile).resize((w, h)))


def _draw_labels(
    sheet: np.ndarray, labels: Sequence[str], columns: int, tile_shape: tuple[int, ...], gap: int
) -> np.ndarray:
    image_cls, draw_cls = _pil()
    image = image_cls.fromarray(sheet)
    draw = draw_cls.Draw(image)
    h, w = tile_shape[:2]
    max_chars = max(1, w // 6)  # the default font is ~6 px per character
    for i, label in enumerate(labels):
        y, x = tile_origin(i, columns, tile_shape, gap, _LABEL_HEIGHT)
        text = label if len(label) <= max_chars else label[: max_chars - 1] + "~"
        draw.text((x + 2, y + h + gap), text, fill=(20, 20, 20))
    return np.asarray(image)

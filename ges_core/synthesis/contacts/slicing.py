"""Horizontal slicing, extremum analysis and the five-finger layout of contact generation.

Points are expressed in *grasp coordinates* ``(g, s, t)``: ``g`` along the squeeze axis (thumb on the
+g side, fingers on the -g side), ``s`` along the finger-spread axis (index -> little), ``t`` along the
approach direction. Heights ``z`` stay in the resting frame (table at z = 0). Metres throughout.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

__all__ = [
    "GraspAxes",
    "Layout",
    "RowWidths",
    "SliceProfile",
    "grasp_axes",
    "horizontal_layouts",
    "pick_extremes",
    "side_masks",
    "slice_profile",
    "thumb_moved",
    "vertical_layouts",
]

MIN_SLICE_POINTS = 3
"""A slice with fewer points has no meaningful extent (its width would be a sampling artefact)."""
SPACING_TIE = 0.001
"""Finger spacings within 1 mm count as equal when choosing a slice (then height decides)."""
BAND_SCALE = 0.5
"""The band searched for a contact's extreme spans half a finger spacing along the row (+-spacing/4):
on a round body the most extreme point of a wider band sits at its inner edge, pulling the index
away from the thumb (pinch) and the fingers together."""
WIDEN_STEPS = 3
"""Times a contact's search band is doubled when it holds no eligible point (sparse clouds)."""


@dataclass(frozen=True)
class GraspAxes:
    """Unit axes (3,) in the resting frame: squeeze ``g``, spread ``s`` (index -> little), approach ``a``."""

    strategy: str
    g: np.ndarray
    s: np.ndarray
    a: np.ndarray

    def matrix(self) -> np.ndarray:
        """(3, 3) with columns g, s, a: ``coords = (p - origin) @ matrix``."""
        return np.column_stack([self.g, self.s, self.a])


@dataclass(frozen=True)
class SliceProfile:
    """Per-slice extremes along g, s, t of points binned by height. Arrays (n_slices,) unless noted."""

    thickness: float
    centers: np.ndarray
    counts: np.ndarray
    lo: np.ndarray
    """(n_slices, 3) smallest g, s, t of each slice."""
    hi: np.ndarray
    """(n_slices, 3) largest g, s, t of each slice."""

    @property
    def width(self) -> np.ndarray:
        """Extent along the squeeze axis g: what the thumb-finger opening must span."""
        return self.hi[:, 0] - self.lo[:, 0]

    def index(self, z: np.ndarray | float) -> np.ndarray:
        """Slice index of height(s) ``z``, clipped to the valid range."""
        return np.clip(np.floor(np.asarray(z) / self.thickness).astype(int), 0, len(self.centers) - 1)


@dataclass(frozen=True)
class Layout:
    """Targets of the five contacts (thumb, index, middle, ring, little) in grasp coordinates."""

    st: np.ndarray
    """(5, 2) target (s, t) of each contact."""
    band: np.ndarray
    """(2,) half-widths of the search band around each target along s and t."""
    spacing: float
    """Distance between neighbouring fingers along s."""
    width: float
    """Squeeze-axis width of the object where the index finger lies."""


def thumb_moved(layout: Layout, shift: float) -> Layout:
    """``layout`` with the thumb's target moved ``shift`` finger spacings along the finger row (index -> little)."""
    if shift == 0.0:
        return layout
    row = layout.st[4] - layout.st[1]
    st = layout.st.copy()
    st[0] += shift * layout.spacing * row / np.linalg.norm(row)
    return replace(layout, st=st)


def grasp_axes(strategy: str, frame: np.ndarray, squeeze_col: int, *, right_hand: bool, flip: bool) -> GraspAxes:
    """Axes of a right (or left) hand grasp squeezing along column ``squeeze_col`` of ``frame``; ``flip``
    puts the thumb on the other side (the same grasp turned 180 deg about z).

    Chirality of a right hand: ``a = d x u`` with ``d = -g`` (thumb -> fingers) and ``u = s``.
    Vertical: ``a = -z``, so ``s = z x g``. Horizontal: the index is on top, ``s = -z``, so ``a = g x z``.
    A left hand mirrors ``s`` (vertical) or ``a`` (horizontal).
    """
    z = np.array([0.0, 0.0, 1.0])
    g = frame[:, squeeze_col] * (-1.0 if flip else 1.0)
    sign = 1.0 if right_hand else -1.0
    if strategy == "vertical":
        return GraspAxes(strategy, g, sign * np.cross(z, g), -z)
    return GraspAxes(strategy, g, -z, sign * np.cross(g, z))


def slice_profile(coords: np.ndarray, z: np.ndarray, thickness: float) -> SliceProfile:
    """Bin points by height into slices of ``thickness`` and take each slice's extremes (vectorized)."""
    n = max(int(np.ceil(z.max() / thickness)), 1)
    idx = np.clip(np.floor(z / thickness).astype(int), 0, n - 1)
    lo, hi = np.full((n, 3), np.inf), np.full((n, 3), -np.inf)
    np.minimum.at(lo, idx, coords)
    np.maximum.at(hi, idx, coords)
    centers = (np.arange(n) + 0.5) * thickness
    return SliceProfile(thickness, centers, np.bincount(idx, minlength=n), lo, hi)


def graspable(profile: SliceProfile, min_width: float, max_width: float) -> np.ndarray:
    """(n_slices,) bool: enough points and a squeeze-axis width a hand can span."""
    w = profile.width
    return (profile.counts >= MIN_SLICE_POINTS) & (w >= min_width) & (w <= max_width)


def vertical_layouts(
    profile: SliceProfile,
    ok: np.ndarray,
    z_range: tuple[float, float],
    z_pref: float,
    cfg,
    rows: RowWidths | None = None,
    s_pref: float | None = None,
):
    """Grasps from above, best first (at most ``cfg.layouts_per_axis``): all contacts in one slice in
    ``z_range``, fingers spread along s. Slices that leave the fingers the widest spacing (within 1 mm) come
    first, nearest ``z_pref`` first among those.

    A graspable slice (``ok``) puts the row at its middle, or with ``s_pref`` (the centre of mass) as near it as
    the slice allows with its edge margins. Another slice may still hold a row where the part under it fits the
    hand (``rows``: a 3 cm handle beside a 13 cm hammer head): the row is moved along s in half spacings from the
    middle, nearest the middle (``s_pref``) first, until the points under it span a graspable width
    (:meth:`RowWidths.width`). Such rows come after every whole-slice layout."""
    inside = np.flatnonzero(
        (profile.counts >= MIN_SLICE_POINTS) & (profile.centers >= z_range[0]) & (profile.centers <= z_range[1])
    )
    extent = (profile.hi[inside, 1] - profile.lo[inside, 1]) * (1.0 - 2.0 * cfg.edge_margin) / 3.0
    room = np.clip(extent, cfg.min_spacing, cfg.finger_spacing)
    order = np.lexsort((np.abs(profile.centers[inside] - z_pref), -np.round(room / SPACING_TIE)))
    ranked = [(int(inside[i]), float(room[i])) for i in order]
    whole = [(k, spacing) for k, spacing in ranked if ok[k]][: cfg.layouts_per_axis]
    out = [_vertical(profile, k, spacing, shift=_toward(profile, k, spacing, cfg, s_pref)) for k, spacing in whole]
    for k, spacing in ranked:  # the whole-slice layouts first: they are what fitted before rows were measured
        if len(out) == cfg.layouts_per_axis or rows is None:
            break
        if not ok[k]:
            out += [layout for layout in [_shifted_row(profile, k, spacing, cfg, rows, s_pref)] if layout is not None]
    return out


def _offset(profile: SliceProfile, k: int, spacing: float, s_pref: float | None) -> float:
    """``s_pref`` (the centre of mass) less slice ``k``'s middle along s; 0 without ``s_pref`` or within half a
    spacing of the middle (the row already straddles it; a few millimetres would only reshuffle the picks)."""
    if s_pref is None:
        return 0.0
    offset = s_pref - 0.5 * (profile.lo[k, 1] + profile.hi[k, 1])
    return float(offset) if abs(offset) > 0.5 * spacing else 0.0


def _toward(profile: SliceProfile, k: int, spacing: float, cfg, s_pref: float | None) -> float:
    """Shift along s from slice ``k``'s middle that centres the finger row as near :func:`_offset` asks as the
    slice allows, its ``edge_margin`` kept free at each end."""
    if not _offset(profile, k, spacing, s_pref):
        return 0.0
    lo, hi = profile.lo[k, 1], profile.hi[k, 1]
    margin = cfg.edge_margin * (hi - lo) + 1.5 * spacing
    if hi - lo <= 2 * margin:
        return 0.0
    return float(np.clip(s_pref, lo + margin, hi - margin) - 0.5 * (lo + hi))


def _vertical(profile: SliceProfile, k: int, spacing: float, shift: float = 0.0, width: float | None = None):
    """Layout in slice ``k``: fingers centred ``shift`` along s from the middle of the slice's s-extent, thumb
    level with the index; ``width``: the squeeze width under the row (default: the slice's)."""
    s_all = _row_s(profile, k, spacing) + shift
    st = np.column_stack([s_all, np.full(5, -profile.centers[k])])  # t = -z for the approach -z
    width = float(profile.width[k]) if width is None else width
    return Layout(st, np.array([0.5 * spacing, profile.thickness]), spacing, width)


def _row_s(profile: SliceProfile, k: int, spacing: float) -> np.ndarray:
    """(5,) s of thumb, index .. little for a row centred on slice ``k``'s s-extent, the thumb opposite the index
    (``thumb_shift`` is applied later, by :func:`thumb_moved`, as in side grasps)."""
    s_f = 0.5 * (profile.lo[k, 1] + profile.hi[k, 1]) + (np.arange(4) - 1.5) * spacing
    return np.concatenate([[s_f[0]], s_f])


def _shifted_row(
    profile: SliceProfile, k: int, spacing: float, cfg, rows: RowWidths, s_pref: float | None = None
) -> Layout | None:
    """The layout of slice ``k`` whose row lies nearest the middle of the slice (``s_pref`` when given) and over a
    graspable width, or None. Every contact's band (+-spacing/4 along s) stays within the slice's s-extent."""
    s_row = _row_s(profile, k, spacing)
    half = BAND_SCALE * 0.5 * spacing
    lo_shift = profile.lo[k, 1] + half - s_row.min()
    hi_shift = profile.hi[k, 1] - half - s_row.max()
    if lo_shift > hi_shift:
        return None
    step = 0.5 * spacing
    shifts = np.arange(np.ceil(lo_shift / step), np.floor(hi_shift / step) + 1) * step
    target = _offset(profile, k, spacing, s_pref)
    for shift in shifts[np.argsort(np.abs(shifts - target), kind="stable")]:
        s = s_row + shift
        width = rows.width(k, s.min() - half, s.max() + half)
        if cfg.min_width <= width <= cfg.max_width:
            return _vertical(profile, k, spacing, shift=float(shift), width=width)
    return None


@dataclass(frozen=True)
class RowWidths:
    """Squeeze widths of the part of a slice under a finger row: what the hand spans when the rest of the
    slice is wider (a hammer's head beside its handle)."""

    coords: np.ndarray
    """(n, 3) grasp coordinates (g, s, t) of the cloud."""
    slice_of: np.ndarray
    """(n,) slice index of each point."""
    facing: np.ndarray
    """(n,) +1 where the outward normal is within ``max_normal_angle_deg`` of +g (a thumb could push there), -1
    within that of -g (a finger could), else 0."""

    @classmethod
    def of(cls, coords: np.ndarray, n_g: np.ndarray, z: np.ndarray, profile: SliceProfile, cfg) -> RowWidths:
        """n_g: (n,) each outward normal's component along g; cfg: the ContactConfig."""
        cos_max = np.cos(np.deg2rad(cfg.max_normal_angle_deg))
        return cls(coords, profile.index(z), (n_g >= cos_max).astype(np.int8) - (n_g <= -cos_max))

    def width(self, k: int, s_lo: float, s_hi: float) -> float:
        """Metres between the outermost +g-facing and the outermost -g-facing points of slice ``k`` with s in
        [s_lo, s_hi]; inf when one side has none. Both sides are required: a sparse slice of a large object
        may hold points of one wall only, whose extent says nothing about the width (a 60 x 50 cm box's 4 mm
        slices hold about 0.2 points per wall under a 7 cm row)."""
        s = self.coords[:, 1]
        here = (self.slice_of == k) & (s >= s_lo) & (s <= s_hi)
        plus, minus = self.coords[here & (self.facing > 0), 0], self.coords[here & (self.facing < 0), 0]
        return float(plus.max() - minus.min()) if len(plus) and len(minus) else float("inf")


def horizontal_layouts(profile: SliceProfile, ok: np.ndarray, z_range: tuple[float, float], z_pref: float, cfg):
    """Grasps from the side, best first (at most ``cfg.layouts_per_axis``): the four fingers stacked in
    height (index on top) in four graspable slices, thumb level with the index. Windows whose middle
    is nearest ``z_pref`` come first; none when the object is too short for the minimum spacing."""
    spacing = min(cfg.finger_spacing, (z_range[1] - z_range[0]) / 3.0)
    if spacing < cfg.min_spacing:
        return []
    tops = profile.centers[(profile.centers >= z_range[0] + 3 * spacing) & (profile.centers <= z_range[1])]
    heights = tops[:, None] - spacing * np.arange(4)[None, :]  # (n_windows, 4) index..little
    heights = heights[ok[profile.index(heights)].all(axis=1)]
    order = np.argsort(np.abs(heights.mean(axis=1) - z_pref), kind="stable")
    return [_horizontal(profile, heights[i], spacing) for i in order[: cfg.layouts_per_axis]]


def _horizontal(profile: SliceProfile, h: np.ndarray, spacing: float) -> Layout:
    """Layout with the fingers at heights ``h`` (4,), each aimed at the middle of its slice along t."""
    k = profile.index(h)
    t_mid = 0.5 * (profile.lo[k, 2] + profile.hi[k, 2])
    st = np.column_stack([np.concatenate([[-h[0]], -h]), np.r_[t_mid[0], t_mid]])  # thumb opposite the index
    return Layout(st, np.array([0.5 * spacing, np.inf]), spacing, float(profile.width[k[0]]))


def side_masks(coords: np.ndarray, n_g: np.ndarray, z: np.ndarray, cfg, rho: float) -> tuple[np.ndarray, np.ndarray]:
    """(n,) bools: points that may hold a contact on the +g side and on the -g side.

    A point qualifies for a side when it is above ``min_height``, its outward normal is within
    ``max_normal_angle_deg`` of that side's outward direction, and it is visible from that side.
    """
    cos_max = np.cos(np.deg2rad(cfg.max_normal_angle_deg))
    high = z >= cfg.min_height
    tree = cKDTree(coords[:, 1:])
    plus = visible(coords, 1.0, high & (n_g >= cos_max), rho, tree)
    return plus, visible(coords, -1.0, high & (-n_g >= cos_max), rho, tree)


def visible(coords: np.ndarray, side: float, candidates: np.ndarray, rho: float, tree: cKDTree) -> np.ndarray:
    """(n,) bool: which ``candidates`` see out of the object along ``side * g``.

    A point is occluded when another point lies ahead of it (by more than ``2 rho`` along the view)
    within a tube of radius ``rho`` around the view ray: an inner wall seen through the object. Points
    on the same smooth surface never occlude each other: at a normal within 60 deg of the view, a
    neighbour ``rho`` off the ray is at most ``1.73 rho`` ahead. ``tree``: KD-tree of ``coords[:, 1:]``
    (the (s, t) plane across the view).
    """
    idx = np.flatnonzero(candidates)
    out = np.zeros(len(coords), dtype=bool)
    if len(idx) == 0:
        return out
    near = tree.query_ball_point(coords[idx, 1:], rho, return_sorted=False)
    owner = np.repeat(np.arange(len(idx)), [len(n) for n in near])
    others = np.concatenate(near).astype(int)
    ahead = side * (coords[others, 0] - coords[idx[owner], 0]) > 2.0 * rho
    out[idx] = np.bincount(owner, weights=ahead, minlength=len(idx)) == 0
    return out


def pick_extremes(coords: np.ndarray, allowed: np.ndarray, layout: Layout, tol: float) -> np.ndarray | None:
    """Extremum analysis: for each contact, the point of its band that is most extreme along the squeeze
    axis (max g for the thumb, min g for the fingers), ties within ``tol`` broken by distance to the
    target. Returns indices (5,) or None when a band stays empty after widening."""
    side = np.array([1.0, -1.0, -1.0, -1.0, -1.0])[:, None]
    off = np.abs(coords[None, :, 1:] - layout.st[:, None, :])  # (5, n, 2)
    for step in range(WIDEN_STEPS + 1):
        band = layout.band * [BAND_SCALE, 1.0] * 2.0**step
        mask = allowed & (off <= band).all(axis=2)
        if mask.any(axis=1).all():
            break
    else:
        return None
    score = np.where(mask, side * coords[None, :, 0], -np.inf)
    near = mask & (score >= score.max(axis=1, keepdims=True) - tol)
    return np.argmin(np.where(near, (off**2).sum(axis=2), np.inf), axis=1)

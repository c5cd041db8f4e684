"""Seeded train / unseen-object / unseen-category splits in the paper's proportions.

The paper splits 773 objects into 563 train, 132 unseen objects of seen categories and 78 objects
of unseen categories. Here, for any list of (id, category):

1. Unseen categories: categories are shuffled (seeded) and taken whole, in that order, while their
   objects still fit in ``round(78 / 773 * N)`` (about 10 % of the objects); a category that would
   overshoot is skipped. At least one category is held out when there are two or more, and at least
   one stays seen.
2. Unseen objects: in every remaining category of ``k`` objects, ``round(132 / 695 * k)`` (about 19 %)
   are drawn (seeded, independently per category) and the rest are train.

Categories named in ``held_out`` are always unseen categories and take no part in steps 1-2: the draw
and the object share are computed over the other categories alone, so pinning a category (or adding a
pinned one) leaves every other object's split as it was.

Deterministic: same ids, categories and seed → same split, whatever the input order.
"""

from __future__ import annotations

import zlib
from collections import defaultdict
from collections.abc import Iterable

import numpy as np

__all__ = ["PAPER_COUNTS", "SPLITS", "assign_splits"]

SPLITS = ("train", "unseen_object", "unseen_category")
PAPER_COUNTS = {"train": 563, "unseen_object": 132, "unseen_category": 78}
"""Object counts of the paper's split (773 objects)."""

UNSEEN_CATEGORY_SHARE = PAPER_COUNTS["unseen_category"] / sum(PAPER_COUNTS.values())  # 0.101
UNSEEN_OBJECT_SHARE = PAPER_COUNTS["unseen_object"] / (PAPER_COUNTS["train"] + PAPER_COUNTS["unseen_object"])  # 0.190


def assign_splits(items: Iterable[tuple[str, str]], *, seed: int = 0, held_out: Iterable[str] = ()) -> dict[str, str]:
    """Map each object id to ``train``, ``unseen_object`` or ``unseen_category``.

    items: (object_id, category) pairs; ids must be unique.
    held_out: categories that are unseen categories whatever the draw (absent ones are ignored).
    """
    groups: dict[str, list[str]] = defaultdict(list)
    for object_id, category in items:
        groups[category].append(object_id)
    groups = {cat: sorted(ids) for cat, ids in sorted(groups.items())}
    pinned = set(held_out) & set(groups)
    unseen = pinned | _unseen_categories({c: ids for c, ids in groups.items() if c not in pinned}, seed)
    split = {}
    for cat, ids in groups.items():
        if cat in unseen:
            split.update(dict.fromkeys(ids, "unseen_category"))
        else:
            split.update(_split_category(cat, ids, seed))
    return split


def _unseen_categories(groups: dict[str, list[str]], seed: int) -> set[str]:
    total = sum(len(ids) for ids in groups.values())
    target = round(UNSEEN_CATEGORY_SHARE * total)
    if len(groups) < 2 or target < 1:
        return set()
    order = list(np.random.default_rng([seed, zlib.crc32(b"unseen_category")]).permutation(sorted(groups)))
    chosen, count = [], 0
    for cat in order:
        if count + len(groups[cat]) <= target and len(chosen) < len(groups) - 1:
            chosen.append(cat)
            count += len(groups[cat])
    if not chosen:  # every category is bigger than the target: hold out the smallest
        chosen = [min(order, key=lambda c: len(groups[c]))]
    return set(chosen)


def _split_category(category: str, ids: list[str], seed: int) -> dict[str, str]:
    n_unseen = round(UNSEEN_OBJECT_SHARE * len(ids))
    rng = np.random.default_rng([seed, zlib.crc32(category.encode())])
    held = set(rng.permutation(len(ids))[:n_unseen].tolist())
    return {oid: "unseen_object" if i in held else "train" for i, oid in enumerate(ids)}

"""Splits: paper proportions, determinism, order independence, disjointness, category semantics."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from ges_core.objects.splits import PAPER_COUNTS, SPLITS, assign_splits


def paper_like_items(seed: int = 0) -> list[tuple[str, str]]:
    """773 objects in 40 categories of uneven size (5-40 objects)."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(5, 41, size=40)
    sizes = np.round(sizes * 773 / sizes.sum()).astype(int)
    sizes[0] += 773 - sizes.sum()
    return [(f"src/cat{c:02d}/{i:03d}", f"cat{c:02d}") for c, n in enumerate(sizes) for i in range(n)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_proportions_follow_the_paper(seed):
    items = paper_like_items()
    counts = Counter(assign_splits(items, seed=seed).values())
    assert sum(counts.values()) == 773
    assert 60 <= counts["unseen_category"] <= PAPER_COUNTS["unseen_category"]
    seen = 773 - counts["unseen_category"]
    assert counts["unseen_object"] / seen == pytest.approx(132 / 695, abs=0.02)


def test_deterministic_and_independent_of_input_order():
    items = paper_like_items()
    a = assign_splits(items, seed=5)
    b = assign_splits(list(reversed(items)), seed=5)
    c = assign_splits(items, seed=6)
    assert a == b
    assert a != c


def test_disjoint_and_category_semantics():
    items = paper_like_items()
    split = assign_splits(items, seed=0)
    assert set(split) == {oid for oid, _ in items} and set(split.values()) <= set(SPLITS)
    by_cat: dict[str, set[str]] = {}
    for oid, cat in items:
        by_cat.setdefault(cat, set()).add(split[oid])
    for cat, splits in by_cat.items():
        if "unseen_category" in splits:
            assert splits == {"unseen_category"}, f"{cat} is partly held out"
        else:
            assert "train" in splits and "unseen_object" in splits  # every category has >= 5 objects
    assert 0.05 <= sum(s == {"unseen_category"} for s in by_cat.values()) / len(by_cat) <= 0.2


def test_small_and_degenerate_inputs():
    assert assign_splits([], seed=0) == {}
    one_category = assign_splits([(f"x/{i}", "x") for i in range(10)], seed=0)
    assert "unseen_category" not in one_category.values()
    assert Counter(one_category.values())["unseen_object"] == 2  # round(0.19 * 10)
    huge_and_tiny = [(f"big/{i}", "big") for i in range(50)] + [("small/0", "small")]
    split = assign_splits(huge_and_tiny, seed=0)
    assert split["small/0"] == "unseen_category" and "unseen_category" not in {split[f"big/{i}"] for i in range(50)}


def test_held_out_categories_are_unseen_and_move_no_other_object():
    items = paper_like_items()
    pinned = [(f"new/{c}/{i:03d}", c) for c in ("newa", "newb") for i in range(12)]
    before = assign_splits(items, seed=3)
    after = assign_splits(items + pinned, seed=3, held_out=("newa", "newb", "absent"))
    assert {oid: after[oid] for oid, _ in items} == before  # every earlier object keeps its split
    assert {after[oid] for oid, _ in pinned} == {"unseen_category"}
    drawn = assign_splits(items + pinned, seed=3)  # not pinned: the draw over all categories moves objects
    assert {oid: drawn[oid] for oid, _ in items} != before
    # a pinned category that the draw would have taken stays unseen, and the draw runs over the rest
    cat = next(c for oid, c in items if before[oid] == "unseen_category")
    rest = [(oid, c) for oid, c in items if c != cat]
    pinned_one = assign_splits(items, seed=3, held_out=(cat,))
    assert {oid: pinned_one[oid] for oid, _ in rest} == assign_splits(rest, seed=3)

"""Expert success by the Stage 1 verdict of each object's grasp (``ges compare-experts --by-grasp``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_dataset import CONFIG, make_record

from ges_core.cli import main
from ges_core.dataset import DatasetWriter, open_dataset
from ges_core.env.evaluate.store import grasp_key
from ges_core.errors import ConfigError
from ges_core.experts.by_grasp import by_grasp, grasp_group
from ges_core.experts.matrix import load_matrix, write_matrix
from ges_core.experts.table import split_rates

# object -> the step its record fails at (None: robust) and the group that gives
CASES = {
    "procedural/box/000": (None, "robust"),
    "procedural/box/001": (None, "robust"),
    "procedural/mug/000": ("robust", "validated"),
    "procedural/mug/001": ("validation", "refined"),
    "procedural/cone/000": ("retargeting", "other"),
}
WINS = {  # object -> (scripted, e1) successes of 4 episodes
    "procedural/box/000": (4, 4),
    "procedural/box/001": (3, 4),
    "procedural/mug/000": (2, 3),
    "procedural/mug/001": (0, 1),
    "procedural/cone/000": (0, 0),
}


@pytest.fixture
def dataset(tmp_path):
    writer = DatasetWriter(tmp_path / "ds", CONFIG)
    for oid, (fail_at, _) in CASES.items():
        writer.add(make_record(oid, "shadow", fail_at=fail_at))
    writer.close()
    return open_dataset(tmp_path / "ds")


def _matrix(path, dataset, keys=None):
    """A matrix of :data:`WINS` on ``dataset``'s shadow records, each object stamped with its grasp key (or
    ``keys``)."""
    keys = keys or {oid: grasp_key(dataset.get(oid, "shadow")) for oid in CASES}
    write_matrix(path, {
        "dataset": str(dataset.root), "run": {"hand": "shadow"}, "baseline": "scripted",
        "experts": {"scripted": {"name": "scripted", "settings": {}}, "e1": {"name": "ppo", "settings": {}}},
        "objects": {oid: {"split": "train", "category": oid.split("/")[1], "cluster": 0, "grasp_key": keys[oid]}
                    for oid in CASES},
        "cells": {oid: {e: {"episodes": 4, "paper": w, "peers": w}
                        for e, w in zip(("scripted", "e1"), WINS[oid], strict=True)} for oid in CASES},
    })  # fmt: skip
    return path


def test_each_record_falls_in_the_group_of_its_stage1_verdict(dataset):
    for oid, (_, group) in CASES.items():
        assert grasp_group(dataset.get(oid, "shadow")) == group, oid


def test_grouped_rates_are_the_episodes_of_each_groups_objects(dataset, tmp_path):
    path = _matrix(tmp_path / "m.json", dataset)
    data = json.loads(path.read_text())
    keys = {oid: e["grasp_key"] for oid, e in data["objects"].items()}
    grouped = by_grasp(load_matrix(path), keys, dataset, "shadow")
    assert dict(zip(grouped.object_ids, grouped.splits, strict=True)) == {o: g for o, (_, g) in CASES.items()}
    for group in ("robust", "validated", "refined", "other"):
        members = [o for o, (_, g) in CASES.items() if g == group]
        want = np.array([WINS[o] for o in members]).sum(axis=0) / (4 * len(members))
        rates = split_rates(grouped, "paper", group)
        assert [rates["scripted"], rates["e1"]] == pytest.approx(want.tolist())


def test_a_changed_record_or_a_missing_one_is_refused_by_name(dataset, tmp_path):
    keys = {oid: grasp_key(dataset.get(oid, "shadow")) for oid in CASES}
    matrix = load_matrix(_matrix(tmp_path / "m.json", dataset))
    with pytest.raises(ConfigError, match="another grasp of 'procedural/mug/000'"):
        by_grasp(matrix, keys | {"procedural/mug/000": "0" * 16}, dataset, "shadow")
    with pytest.raises(ConfigError, match="no 'allegro' record of 'procedural/box/000'"):
        by_grasp(matrix, keys, dataset, "allegro")
    assert by_grasp(matrix, dict.fromkeys(keys), dataset, "shadow").splits[0] == "robust"  # no key stored: unchecked


def test_cli_prints_and_writes_the_groups(dataset, tmp_path, capsys):
    path, out = _matrix(tmp_path / "m.json", dataset), tmp_path / "cmp.json"
    assert main(["compare-experts", str(path), "--by-grasp", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "objects: robust 2, validated 1, refined 1, other 1" in text
    assert "| scripted (baseline) | 87.5 % (7/8) | 50.0 % (2/4) | 0.0 % (0/4) | 0.0 % (0/4) |" in text
    written = json.loads(out.read_text())["by_grasp"]
    assert written["groups"] == {"robust": 2, "validated": 1, "refined": 1, "other": 1}
    assert written["rates"]["robust"]["e1"] == 1.0
    assert {r["split"] for r in written["rows"]} == {"robust", "validated", "refined", "other", "all"}
    bad = _matrix(tmp_path / "bad.json", dataset, dict.fromkeys(CASES, "f" * 16))
    assert main(["compare-experts", str(bad), "--by-grasp", str(dataset.root)]) == 1
    assert "rerun ges eval-experts" in capsys.readouterr().err

"""Gates (issue 14): the three plugins, the KL training, checkpoints and bad input.

Data: real surface clouds of procedural library objects; the "success rates" are a geometric rule on
their real sizes (expert "small" wins below the 1/3 quantile of the longest side, "large" above 2/3,
"medium" between), so a gate has something real to learn without PPO experts. Models are tiny (settings).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.stats
import torch
import torch.nn.functional as F

from ges_core.errors import ArrayError, ConfigError, StorageError
from ges_core.gating import (
    AugmentConfig,
    GateData,
    ResampledCloudWarning,
    SuccessRates,
    TrainConfig,
    augment,
    fit_cloud,
    gate_accuracy,
    kl_loss,
    library_clouds,
    load_gate,
    split_indices,
    targets,
)
from ges_core.gating.checkpoint import read_pick_rule
from ges_core.gating.ops import ball_query, farthest_point_sample, knn
from ges_core.registry import load_registry

N_POINTS = 128
TINY = {
    "curvenet": {
        "n_points": N_POINTS,
        "k": 8,
        "stem": 8,
        "stages": [
            {"channels": 16, "points": None, "radius": 0.2, "curves": [8, 4]},
            {"channels": 16, "points": 32, "radius": 0.5, "curves": None},
        ],
        "embed": 32,
        "head": [16],
    },
    "pointnet2": {
        "n_points": N_POINTS,
        "levels": [{"centres": 32, "radius": 0.3, "group": 8, "mlp": [16, 16]}],
        "global_mlp": [32],
        "head": [16],
    },
    "centroid": {"n_points": N_POINTS},
}
EXPERTS = ("small", "medium", "large")
FAST = TrainConfig(epochs=2, batch_size=8, val_fraction=0.25)


@pytest.fixture(scope="module")
def registry():
    return load_registry()


@pytest.fixture(scope="module")
def data() -> GateData:
    """24 procedural objects (3 per category), their clouds and size-rule success rates."""
    from ges_core.objects.library import LibraryConfig, ObjectLibrary

    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=3))
    ids = [o.object_id for o in library.list()][:24]
    size = np.array([library.extents(i).max() for i in ids])
    lo, hi = np.quantile(size, [1 / 3, 2 / 3])
    best = np.where(size < lo, 0, np.where(size < hi, 1, 2))
    rates = np.full((len(ids), 3), 0.1)
    rates[np.arange(len(ids)), best] = 0.9
    return GateData(SuccessRates(ids, EXPERTS, rates), library_clouds(library, ids, N_POINTS))


def build(registry, name: str):
    return registry.spec("gate", name).load()(**TINY[name])


@pytest.fixture(scope="module")
def fitted(registry, data) -> dict:
    """Each gate fitted for 2 epochs (the centroid gate: its centres)."""
    gates = {}
    for name in TINY:
        gate = build(registry, name)
        gate.fit(data, FAST)
        gates[name] = gate
    return gates


# -- the three plugins -------------------------------------------------------------------------------
def test_every_gate_is_registered_and_builds_by_name(registry):
    assert {"curvenet", "pointnet2", "centroid"} <= set(registry.names("gate"))
    for name in TINY:
        gate = build(registry, name)
        assert gate.name == name and gate.experts == ()


@pytest.mark.parametrize("name", list(TINY))
def test_predict_shapes_and_rows_sum_to_one(fitted, data, name):
    gate = fitted[name]
    probs = gate.predict(data.clouds[:5])
    assert probs.shape == (5, 3) and probs.dtype == torch.float32
    assert torch.allclose(probs.sum(dim=1), torch.ones(5), atol=1e-5) and (probs >= 0).all()
    assert gate.experts == EXPERTS
    assert torch.equal(gate.select(data.clouds[:5]), probs.argmax(dim=1))


@pytest.mark.parametrize("name", list(TINY))
def test_point_order_does_not_matter(fitted, data, name):
    clouds = data.clouds[:6]
    perm = torch.randperm(N_POINTS, generator=torch.Generator().manual_seed(3))
    a, b = fitted[name].predict(clouds), fitted[name].predict(clouds[:, perm])
    assert torch.allclose(a, b, atol=1e-4), (a - b).abs().max()


@pytest.mark.parametrize("name", list(TINY))
def test_save_load_round_trip_gives_identical_predictions(registry, fitted, data, name, tmp_path):
    path = tmp_path / f"{name}.pt"
    fitted[name].save(path)
    loaded = load_gate(path, registry)
    assert type(loaded) is type(fitted[name]) and loaded.experts == EXPERTS
    assert torch.equal(loaded.predict(data.clouds), fitted[name].predict(data.clouds))
    assert list(tmp_path.iterdir()) == [path]  # atomic write leaves no temporary file


def test_gate_used_with_other_experts_names_both_lists(registry, fitted, tmp_path):
    path = tmp_path / "g.pt"
    fitted["pointnet2"].save(path)
    with pytest.raises(ConfigError) as err:
        load_gate(path, registry, experts=["small", "large", "medium"])
    msg = str(err.value)
    assert "['small', 'medium', 'large']" in msg and "['small', 'large', 'medium']" in msg
    load_gate(path, registry, experts=list(EXPERTS)).check_experts(EXPERTS)  # the right list passes


def test_a_checkpoint_of_one_gate_is_refused_by_another(registry, fitted, tmp_path):
    path = tmp_path / "g.pt"
    fitted["centroid"].save(path)
    with pytest.raises(ConfigError, match="holds a 'centroid' gate"):
        registry.spec("gate", "curvenet").load().load(path)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="not a readable gate checkpoint"):
        load_gate(tmp_path / "junk.pt", registry)


def test_an_untrained_gate_says_so(registry, data):
    for name in TINY:
        with pytest.raises(ConfigError, match="not (trained|fitted)"):
            build(registry, name).predict(data.clouds[:1])


# -- training ---------------------------------------------------------------------------------------
def test_kl_loss_matches_torch_and_scipy():
    gen = torch.Generator().manual_seed(0)
    logits = torch.randn(7, 4, generator=gen, dtype=torch.float64)
    p = torch.rand(7, 4, generator=gen, dtype=torch.float64)
    p[0, 1] = 0.0  # a zero target entry: 0 log 0 = 0
    p = p / p.sum(dim=1, keepdim=True)
    ours = float(kl_loss(logits, p))
    q = torch.softmax(logits, dim=1)
    ref_torch = float(F.kl_div(torch.log_softmax(logits, dim=1), p, reduction="batchmean"))
    ref_scipy = float(np.mean(scipy.stats.entropy(p.numpy(), q.numpy(), axis=1)))
    assert ours == pytest.approx(ref_torch, rel=1e-9) and ours == pytest.approx(ref_scipy, rel=1e-9)
    assert float(kl_loss(torch.log(p.clamp_min(1e-300)), p)) == pytest.approx(0.0, abs=1e-9)


def test_targets_normalize_and_all_failed_objects_are_dropped_or_uniform():
    rates = SuccessRates(("a", "b", "c"), ("x", "y"), np.array([[0.5, 0.25], [0.0, 0.0], [0.0, 1.0]]))
    kept, p = targets(rates)
    assert kept.tolist() == [0, 2] and np.allclose(p, [[2 / 3, 1 / 3], [0.0, 1.0]])
    kept, p = targets(rates, "uniform")
    assert kept.tolist() == [0, 1, 2] and np.allclose(p[1], [0.5, 0.5]) and np.allclose(p.sum(axis=1), 1)


def test_gate_accuracy_counts_a_pick_among_tied_best_experts():
    rates = np.array([[0.5, 0.5, 0.0], [0.1, 0.9, 0.2], [0.3, 0.2, 0.1]])
    probs = np.array([[0.1, 0.8, 0.1], [0.6, 0.3, 0.1], [0.5, 0.4, 0.1]])
    assert gate_accuracy(probs, rates) == pytest.approx(2 / 3)  # row 0: tie counts, row 1 wrong, row 2 right


def test_split_is_seeded_disjoint_and_complete():
    tr, va = split_indices(20, 0.25, seed=1)
    assert len(va) == 5 and sorted([*tr, *va]) == list(range(20))
    assert np.array_equal(va, split_indices(20, 0.25, seed=1)[1])
    assert not np.array_equal(va, split_indices(20, 0.25, seed=2)[1])


def test_tiny_training_run_lowers_the_loss(registry, data):
    gate = build(registry, "pointnet2")
    config = TrainConfig(epochs=20, batch_size=6, val_fraction=0.25, lr=3e-3, keep="last")
    history = gate.fit(data, config).history
    losses = [h["loss/train"] for h in history]
    assert np.mean(losses[-3:]) < 0.8 * np.mean(losses[:3]), [round(x, 3) for x in losses]


def test_same_seed_gives_identical_weights_and_another_seed_does_not(registry, data, tmp_path):
    def weights(seed: int) -> dict:
        gate = build(registry, "curvenet")
        gate.fit(data, TrainConfig(epochs=2, batch_size=8, seed=seed))
        return gate.model.state_dict()

    a, b, c = weights(0), weights(0), weights(1)
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_training_writes_tensorboard_curves(registry, data, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    build(registry, "pointnet2").fit(data, FAST, log_dir=tmp_path / "tb")
    events = EventAccumulator(str(tmp_path / "tb"))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    assert {"loss/train", "loss/val", "accuracy/train", "accuracy/val", "lr"} <= tags
    assert [e.step for e in events.Scalars("loss/train")] == [1, 2]


def test_augmentation_rotates_about_z_and_scales_within_the_band():
    gen = torch.Generator().manual_seed(0)
    pts = torch.rand(4, 50, 3)
    out = augment(pts, AugmentConfig(scale=0.1), gen)
    factor = out[..., 2] / pts[..., 2]  # z only scales
    assert torch.allclose(factor, factor[:, :1].expand_as(factor), atol=1e-5)
    assert ((factor[:, 0] >= 0.9 - 1e-6) & (factor[:, 0] <= 1.1 + 1e-6)).all()
    radial = out[..., :2].norm(dim=-1) / pts[..., :2].norm(dim=-1)  # xy norms scale by the same factor: a rotation
    assert torch.allclose(radial, factor, atol=1e-4)
    assert not torch.allclose(out[..., :2] / factor[..., None], pts[..., :2], atol=1e-3)  # it did rotate
    assert torch.equal(augment(pts, AugmentConfig(enabled=False), gen), pts)
    again = augment(pts, AugmentConfig(scale=0.1), torch.Generator().manual_seed(0))
    assert torch.equal(again, out)


# -- bad input -------------------------------------------------------------------------------------
def test_a_short_cloud_is_resampled_with_a_warning_naming_the_object():
    pts = np.random.default_rng(0).random((40, 3))
    with pytest.warns(ResampledCloudWarning, match="procedural/mug/007.*40 points.*64"):
        out = fit_cloud(pts, 64, "procedural/mug/007")
    assert out.shape == (64, 3)
    assert np.allclose(out[:40], pts, atol=1e-6)  # every original point kept, the rest repeats of them
    assert all(np.isclose(out[40:, None], pts[None]).all(-1).any(-1))


def test_a_long_cloud_is_thinned_by_farthest_points_without_warning(recwarn):
    pts = np.random.default_rng(0).random((300, 3))
    out = fit_cloud(pts, 64, "x")
    assert out.shape == (64, 3) and not recwarn.list


@pytest.mark.parametrize(
    ("cloud", "match"),
    [
        (np.zeros((0, 3)), "object 'bowl/3': point cloud is empty"),
        (np.array([[0.0, 0.0, np.nan]] * 5), "object 'bowl/3': 5 of 5 points are NaN"),
        (np.zeros((10, 2)), r"object 'bowl/3': point cloud has shape \(10, 2\)"),
    ],
)
def test_bad_clouds_are_errors_naming_the_object(cloud, match):
    with pytest.raises(ArrayError, match=match):
        fit_cloud(cloud, 64, "bowl/3")


@pytest.mark.parametrize("name", list(TINY))
def test_predict_names_the_object_of_a_nan_cloud_and_resamples_short_ones(fitted, data, name):
    clouds = data.clouds[:3].clone()
    clouds[1, 7, 0] = float("nan")
    with pytest.raises(ArrayError, match="object 'b': 1 of 128 points are NaN"):
        fitted[name].predict(clouds, object_ids=["a", "b", "c"])
    with pytest.warns(ResampledCloudWarning, match="object 'a'"):
        probs = fitted[name].predict([data.clouds[0, :50].numpy()], object_ids=["a"])
    assert probs.shape == (1, 3)


def test_bad_success_rates_are_clear_errors():
    with pytest.raises(ArrayError, match="expert 'y' on object 'b' is 1.5"):
        SuccessRates(("a", "b"), ("x", "y"), np.array([[0.1, 0.2], [0.3, 1.5]]))
    with pytest.raises(ConfigError, match="at least 2 experts"):
        SuccessRates(("a",), ("x",), np.array([[0.1]]))
    with pytest.raises(ConfigError, match=r"object ids repeated: \['a'\]"):
        SuccessRates(("a", "a"), ("x", "y"), np.zeros((2, 2)))


# -- point operations --------------------------------------------------------------------------------
def test_point_ops_against_brute_force():
    gen = torch.Generator().manual_seed(0)
    xyz = torch.rand(2, 200, 3, generator=gen)
    d = ((xyz[:, :, None] - xyz[:, None]) ** 2).sum(-1)
    idx = knn(xyz, 5)
    assert torch.equal(idx[..., 0], torch.arange(200).expand(2, 200))  # itself first
    assert torch.allclose(torch.gather(d, 2, idx), d.sort(dim=-1).values[..., :5], atol=1e-6)
    fps = farthest_point_sample(xyz, 20)
    assert all(len(set(row.tolist())) == 20 for row in fps)
    chosen = torch.gather(xyz, 1, fps[..., None].expand(-1, -1, 3))
    spacing = torch.cdist(chosen, chosen) + torch.eye(20) * 9
    rand = xyz[:, :20]
    assert (
        spacing.min(-1).values.min(-1).values
        > (torch.cdist(rand, rand) + torch.eye(20) * 9).min(-1).values.min(-1).values
    ).all()
    ball = ball_query(xyz, chosen, 0.1, 8)
    dist = torch.gather(torch.cdist(chosen, xyz), 2, ball)
    assert (dist <= 0.1 + 1e-6).all()


# -- ges train-gate on a matrix file ------------------------------------------------------------------
DATASET = "tests/data/dataset_v2"  # its library: procedural (10 per category) + pybullet
CLI_CONFIG = """
gate: pointnet2
settings:
  n_points: 128
  levels: [{centres: 32, radius: 0.3, group: 8, mlp: [16, 16]}]
  global_mlp: [32]
  head: [16]
train: {epochs: 3, batch_size: 6, val_fraction: 0.25}
checkpoint_every: 2
"""


# -- category smoothing of the targets (TrainConfig.category_smoothing) ------------------------------------------------
def test_category_smoothing_mixes_each_row_with_its_categorys_mean_over_the_given_rows_only():
    from ges_core.gating.data import category_smoothed

    rng = np.random.default_rng(3)
    rates = rng.uniform(0, 1, (12, 3))
    categories = [("mug", "box", "can")[i] for i in rng.integers(0, 3, 12)]
    rows = np.array([0, 2, 3, 5, 6, 8, 9, 11])
    for weight in (0.0, 0.3, 1.0):
        expected = [
            (1 - weight) * rates[r]
            + weight * np.mean([rates[j] for j in rows if categories[j] == categories[r]], axis=0)
            for r in rows
        ]
        np.testing.assert_allclose(category_smoothed(rates, categories, rows, weight), expected, rtol=0, atol=1e-12)
    elsewhere = rates.copy()
    elsewhere[[1, 4, 7, 10]] = rng.uniform(0, 1, (4, 3))  # the rows left out (validation) never reach the result
    np.testing.assert_array_equal(category_smoothed(elsewhere, categories, rows, 0.5),
                                  category_smoothed(rates, categories, rows, 0.5))  # fmt: skip
    with pytest.raises(ArrayError, match="11 categories for 12 rows"):
        category_smoothed(rates, categories[:11], rows, 0.5)


def test_training_with_category_smoothing_is_training_on_the_smoothed_rates(registry, data):
    """A gate trained with smoothing 1 has the weights of one trained without it on rates whose training rows were
    replaced by their category's mean over the training rows (validation rows as they were); and not those of the
    unsmoothed run."""
    categories = tuple(i.split("/")[1] for i in data.rates.object_ids)  # procedural/<category>/<n>
    config = TrainConfig(epochs=2, batch_size=8, val_fraction=0.25)
    train_rows, _ = split_indices(len(categories), config.val_fraction, config.seed)
    smoothed = data.rates.rates.copy()
    for c in set(categories):
        same = [r for r in train_rows if categories[r] == c]
        smoothed[same] = data.rates.rates[same].mean(axis=0)

    def weights(gate_data: GateData, weight: float) -> dict:
        gate = build(registry, "pointnet2")
        gate.fit(gate_data, config.model_copy(update={"category_smoothing": weight}))
        return gate.model.state_dict()

    with_smoothing = weights(GateData(data.rates, data.clouds, categories), 1.0)
    by_hand = weights(GateData(SuccessRates(data.rates.object_ids, EXPERTS, smoothed), data.clouds), 0.0)
    plain = weights(GateData(data.rates, data.clouds, categories), 0.0)
    assert all(torch.equal(with_smoothing[k], by_hand[k]) for k in with_smoothing)
    assert not all(torch.equal(with_smoothing[k], plain[k]) for k in with_smoothing)
    with pytest.raises(ConfigError, match="train.category_smoothing needs each object's category"):
        build(registry, "pointnet2").fit(data, config.model_copy(update={"category_smoothing": 0.5}))


def _matrix_file(tmp_path) -> tuple:
    """A matrix file in ges eval-experts' format over 30 library objects of every split; the cells follow the
    size rule (4 episodes each), plus the scripted baseline column that the gate must leave out."""
    from ges_core.dataset import open_dataset
    from ges_core.env.grasp_source import library_for
    from ges_core.experts.matrix import write_matrix

    library = library_for(open_dataset(DATASET))
    infos = [o for o in library.list(source="procedural")][::2][:30]
    size = np.array([library.extents(o.object_id).max() for o in infos])
    lo, hi = np.quantile(size, [1 / 3, 2 / 3])
    best = np.where(size < lo, 0, np.where(size < hi, 1, 2))
    experts = {e: {"name": "scripted", "settings": {"close_steps": 40 + 10 * i}} for i, e in enumerate(EXPERTS)}
    experts["scripted"] = {"name": "scripted", "settings": {}}
    objects, cells = {}, {}
    for o, b in zip(infos, best, strict=True):
        objects[o.object_id] = {"split": o.split, "category": o.category, "cluster": None, "grasp_key": "k"}
        wins = {e: (4 if i == b else 1) for i, e in enumerate(EXPERTS)} | {"scripted": 2}
        cells[o.object_id] = {e: {"episodes": 4, "paper": w, "peers": w} for e, w in wins.items()}
    path = tmp_path / "matrix-shadow-sapien.json"
    write_matrix(path, {"dataset": str(Path(DATASET).resolve()), "run": {}, "experts": experts,
                        "baseline": "scripted", "objects": objects, "cells": cells})  # fmt: skip
    return path, infos


def test_ges_train_gate_end_to_end_on_a_matrix_file(tmp_path, capsys, registry):
    from ges_core.cli import main

    matrix, infos = _matrix_file(tmp_path)
    (tmp_path / "gate.yaml").write_text(CLI_CONFIG)
    out = tmp_path / "gate"
    assert main(["train-gate", str(matrix), "--config", str(tmp_path / "gate.yaml"), "--out", str(out)]) == 0
    table, bar = capsys.readouterr()
    assert re.search(r"gate pointnet2: 100%.* 3/3 .*loss train=[0-9.]+, loss val=[0-9.]+", bar), bar  # the epochs
    assert "gate pointnet2 (128 points) over experts small, medium, large" in table
    for split in ("train", "val", "unseen_object", "unseen_category"):
        assert f"| {split} |" in table
    assert {"gate.pt", "tb", "history.json", "summary.json", "clouds-128-0.pt"} <= {p.name for p in out.iterdir()}
    summary = json.loads((out / "summary.json").read_text())
    assert summary["matrix"] == str(matrix.resolve())  # absolute: `ges evaluate --gate` finds it from any folder
    n_train = sum(o.split == "train" for o in infos)
    assert summary["counts"]["train"] + summary["counts"]["val"] == n_train
    assert len(json.loads((out / "history.json").read_text())) == 3
    gate = load_gate(out / "gate.pt", registry, experts=list(EXPERTS))  # the baseline column is not an expert
    assert gate.predict(torch.zeros(1, 128, 3) + torch.rand(1, 128, 3) * 0.05).shape == (1, 3)
    rule = read_pick_rule(out / "gate.pt")  # fitted on the held-out objects after training, stored with the weights
    assert rule.fallback in EXPERTS and summary["pick"] == rule.to_json()
    assert f"pick: {rule.describe()}" in table and "success of the rule's picks" in table
    assert set(summary["picked"]) == {"train", "val", "unseen_object", "unseen_category"}
    smooth = tmp_path / "smooth"  # the categories come from the matrix file
    args = ["train-gate", str(matrix), "--config", str(tmp_path / "gate.yaml"), "-o", "train.category_smoothing=0.5"]
    assert main([*args, "--out", str(smooth)]) == 0
    assert json.loads((smooth / "summary.json").read_text())["config"]["train"]["category_smoothing"] == 0.5
    capsys.readouterr()
    paper = tmp_path / "paper"
    assert main(["train-gate", str(matrix), "--gate", "centroid", "-o", "pick=argmax", "--out", str(paper)]) == 0
    assert read_pick_rule(paper / "gate.pt").fallback is None and "pick: argmax" in capsys.readouterr().out


def test_ges_train_gate_errors_are_one_line(tmp_path, capsys):
    from ges_core.cli import main

    matrix, _ = _matrix_file(tmp_path)
    assert main(["train-gate", str(matrix), "--gate", "nope", "--out", str(tmp_path / "o")]) == 1
    assert "nope" in capsys.readouterr().err
    assert main(["train-gate", str(matrix), "-o", "experts=[small,huge]", "--out", str(tmp_path / "o")]) == 1
    assert "expert column(s) ['huge'] not in the matrix" in capsys.readouterr().err


def test_train_gate_pools_matrices_of_other_seeds(tmp_path, capsys):
    """Several matrix files: the targets are the summed successes over the summed episodes (a numpy computation on
    the files), ``--experts`` keeps those columns, and a file of other objects is refused naming them."""
    from ges_core.cli import main
    from ges_core.experts.matrix import read_matrix_json, write_matrix
    from ges_core.gating.sources import load_rates

    first, _ = _matrix_file(tmp_path)
    data = read_matrix_json(first)
    rng = np.random.default_rng(3)
    for cells in data["cells"].values():
        for cell in cells.values():
            cell["paper"] = cell["peers"] = int(rng.integers(0, 5))
    second = tmp_path / "seed1" / first.name
    write_matrix(second, data)
    pooled = load_rates(first, columns=["large", "small"], pool=[second])
    files = [read_matrix_json(p) for p in (first, second)]
    for i, oid in enumerate(pooled.rates.object_ids):
        for j, e in enumerate(("large", "small")):
            wins = sum(f["cells"][oid][e]["paper"] for f in files)
            assert pooled.rates.rates[i, j] == wins / 8
    alone = load_rates(second, columns=["large", "small"])
    assert not np.array_equal(alone.rates.rates, pooled.rates.rates)

    del data["objects"][next(iter(data["objects"]))]
    other = tmp_path / "other" / first.name
    write_matrix(other, data)
    assert main(["train-gate", str(first), str(other), "--experts", "small,large", "--out", str(tmp_path / "o")]) == 1
    assert "holds other objects than matrix 1" in capsys.readouterr().err
    assert main(["train-gate", str(first), str(second), "--experts", "small,huge", "--out", str(tmp_path / "o")]) == 1
    assert "no expert column 'huge'" in capsys.readouterr().err


# -- the centroid gate with a real clustering ----------------------------------------------------------
@pytest.fixture(scope="module")
def clusters_file(data, tmp_path_factory):
    """``ges cluster``'s clustering (k = 3, mesh features) of the fixture's objects, written as clusters.json."""
    from ges_core.clustering import ClusterConfig, ObjectShape, cluster_objects, object_features, save_clusters
    from ges_core.objects.library import LibraryConfig, ObjectLibrary

    library = ObjectLibrary(LibraryConfig(sources=("procedural",), procedural_count=3))
    shapes = [
        ObjectShape(oid, library.entry(oid).category, "train", object_features(library, oid, points=1024, seed=0))
        for oid in data.rates.object_ids
    ]
    clusters = cluster_objects(shapes, ClusterConfig(k=3))
    return save_clusters(clusters, tmp_path_factory.mktemp("clusters") / "clusters.json"), clusters


def test_centroid_gate_uses_the_clustering_and_its_cluster_to_expert_map(registry, data, clusters_file):
    path, clusters = clusters_file
    mapping = {0: "large", 1: "small", 2: "medium"}
    gate = registry.spec("gate", "centroid").load()(n_points=N_POINTS, clusters=str(path), cluster_experts=mapping)
    gate.fit(data, FAST)
    assert "clustering" in gate.train_info["centres"] and "cluster_experts setting" in gate.train_info["centres"]
    # independently: the cloud's features, standardized as the clustering does, nearest of its centres
    from ges_plugins.gates.centroid.gate import cloud_features

    feats = np.stack([cloud_features(c.numpy()) for c in data.clouds])
    nearest = np.linalg.norm(clusters.standardize(feats)[:, None] - clusters.centres[None], axis=-1).argmin(axis=1)
    expected = [EXPERTS.index(mapping[c]) for c in nearest]
    assert gate.select(data.clouds).tolist() == expected
    # the hull stands in for the mesh: the cloud's nearest centre mostly agrees with the clustering's own
    agree = np.mean(
        [clusters.objects[o].nearest_cluster == c for o, c in zip(data.rates.object_ids, nearest, strict=True)]
    )
    assert agree >= 0.75, agree


def test_centroid_gate_maps_each_cluster_to_its_best_expert_when_not_told(registry, data, clusters_file):
    path, clusters = clusters_file
    gate = registry.spec("gate", "centroid").load()(n_points=N_POINTS, clusters=str(path))
    result = gate.fit(data, FAST)
    train = [data.rates.object_ids.index(o) for o in result.train_ids]
    for c in range(clusters.k):
        rows = [r for r in train if clusters.objects[data.rates.object_ids[r]].cluster == c]
        assert int(gate.state["owner"][c]) == int(data.rates.rates[rows].mean(axis=0).argmax())
    with pytest.raises(ConfigError, match=r"missing \[2\]"):
        registry.spec("gate", "centroid").load()(
            n_points=N_POINTS, clusters=str(path), cluster_experts={0: "small", 1: "large"}
        ).fit(data, FAST)


def test_centroid_gate_without_clustering_says_so(registry, fitted):
    assert fitted["centroid"].train_info["centres"].startswith("no clustering given")


def test_farthest_point_sampling_is_the_same_on_both_paths():
    xyz = torch.rand(6, 300, 3, generator=torch.Generator().manual_seed(1))
    batched = farthest_point_sample(xyz, 40)  # 6 > NUMPY_FPS_MAX_BATCH: the torch loop
    one_by_one = torch.cat([farthest_point_sample(xyz[i : i + 1], 40) for i in range(6)])  # numpy
    assert torch.equal(batched, one_by_one)


def test_curvenet_inference_walk_matches_the_training_walk(fitted, data):
    model = fitted["curvenet"].model.eval()
    x = data.clouds[:4] / fitted["curvenet"].settings.input_scale
    with torch.no_grad():
        fast = model(x)  # argmax and gather
    with torch.enable_grad():
        straight_through = model(x)  # one-hot products whose forward value is the same choice
    assert torch.allclose(fast, straight_through.detach(), atol=1e-5)


# -- resuming a killed training run ------------------------------------------------------------------
class _Killed(Exception):
    """Stands in for a SIGKILL after an epoch (the state on disk is what a killed run leaves)."""


def _kill_after(epoch: int):
    def on_epoch(e, _result):
        if e == epoch:
            raise _Killed

    return on_epoch


@pytest.mark.parametrize("name", ["curvenet", "pointnet2"])
def test_a_killed_training_run_resumes_to_the_same_weights_and_curves(registry, data, tmp_path, name):
    """Killed after epoch 3 with the state last written at epoch 2 (every 2 epochs), then resumed: the same
    final weights (keep=last: epoch 5's), best-epoch bookkeeping and history as 5 epochs straight, which needs
    the Adam moments, the augmentation stream and torch's global stream (dropout) restored."""
    config = TrainConfig(epochs=5, batch_size=8, val_fraction=0.25, keep="last")
    straight = build(registry, name)
    reference = straight.fit(data, config, state_file=tmp_path / "a.pt", state_every=2)
    state = tmp_path / "b.pt"
    with pytest.raises(_Killed):
        build(registry, name).fit(data, config, state_file=state, state_every=2, on_epoch=_kill_after(3))
    assert torch.load(state, weights_only=True)["epoch"] == 2
    resumed_gate = build(registry, name)
    resumed = resumed_gate.fit(data, config, state_file=state, state_every=2, resume=True)
    a, b = straight.model.state_dict(), resumed_gate.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert resumed.kept_epoch == reference.kept_epoch == 5 and resumed.history == reference.history
    # the epochs after the kill changed the weights: the equality above covers them
    short = build(registry, name)
    short.fit(data, config.model_copy(update={"epochs": 3}))
    assert not all(torch.equal(a[k], short.model.state_dict()[k]) for k in a)


def test_resuming_from_a_state_of_other_settings_names_what_differs(registry, data, tmp_path):
    state = tmp_path / "s.pt"
    build(registry, "pointnet2").fit(data, FAST, state_file=state, state_every=1)
    other = TrainConfig(epochs=2, batch_size=8, val_fraction=0.25, lr=5e-3)
    with pytest.raises(ConfigError, match="other config"):
        build(registry, "pointnet2").fit(data, other, state_file=state, resume=True)
    (tmp_path / "junk.pt").write_bytes(b"not a state")
    with pytest.raises(StorageError, match="not a readable gate training state"):
        build(registry, "pointnet2").fit(data, FAST, state_file=tmp_path / "junk.pt", resume=True)


def test_ges_train_gate_resume_after_a_kill_ends_as_an_unbroken_run(tmp_path, capsys, monkeypatch):
    """The CLI: a run killed after its epoch-2 checkpoint, resumed with --resume, writes the same history,
    summary accuracies and gate weights as a run that never stopped; --resume without a state starts over."""
    from ges_core.cli import main
    from ges_core.gating import train as train_module

    matrix, _ = _matrix_file(tmp_path)
    (tmp_path / "gate.yaml").write_text(CLI_CONFIG)
    args = ["train-gate", str(matrix), "--config", str(tmp_path / "gate.yaml"), "--out"]
    assert main([*args, str(tmp_path / "straight"), "--no-progress"]) == 0
    assert "gate pointnet2:" not in capsys.readouterr().err  # no bar
    real_log = train_module._log

    def dying_log(writer, row):
        real_log(writer, row)
        if row["epoch"] == 3:
            raise KeyboardInterrupt  # after epoch 3's curves, before its state: the state on disk is epoch 2's

    monkeypatch.setattr(train_module, "_log", dying_log)
    assert main([*args, str(tmp_path / "killed")]) == 130  # Ctrl-C's exit status
    monkeypatch.setattr(train_module, "_log", real_log)
    assert torch.load(tmp_path / "killed" / "train_state.pt", weights_only=True)["epoch"] == 2
    assert main([*args, str(tmp_path / "killed"), "--resume"]) == 0
    for name in ("history.json",):
        assert (tmp_path / "killed" / name).read_text() == (tmp_path / "straight" / name).read_text()
    done = [json.loads((tmp_path / d / "summary.json").read_text()) for d in ("straight", "killed")]
    assert done[0]["accuracy"] == done[1]["accuracy"] and done[0]["kept_epoch"] == done[1]["kept_epoch"]
    a, b = (torch.load(tmp_path / d / "gate.pt", weights_only=True)["state"] for d in ("straight", "killed"))
    assert all(torch.equal(a[k], b[k]) for k in a)
    capsys.readouterr()
    assert main([*args, str(tmp_path / "new"), "--resume"]) == 0  # nothing to resume: trains from epoch 1
    assert json.loads((tmp_path / "new" / "history.json").read_text()) == json.loads(
        (tmp_path / "straight" / "history.json").read_text()
    )

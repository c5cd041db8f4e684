"""Gates trained on K folds and averaged (``train.folds``, ``ges train-gate --folds``).

Cross-checks against independent computations: the fold split against set arithmetic, the averaged gate against the
mean of its members' own predictions (each loaded from its own file), the out-of-fold scores against the member
files, the stored pick rule against ``fit_pick_rule`` run on those scores, a kill in the middle of fold 2 against a
run that never stopped.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_gates import CLI_CONFIG, EXPERTS, TINY, _matrix_file, build, data, registry  # noqa: F401 - fixtures

from ges_core.errors import ConfigError
from ges_core.gating import GateData, SuccessRates, TrainConfig, load_gate
from ges_core.gating.checkpoint import read_checkpoint, read_pick_rule
from ges_core.gating.data import fold_indices
from ges_core.gating.fallback import fit_pick_rule
from ges_core.gating.folds import train_folds
from ges_core.gating.torch_gate import MeanOfMembers

FOLDS = TrainConfig(epochs=2, batch_size=8, folds=3)


def test_folds_partition_the_objects_each_held_out_once():
    for n, k, seed in ((10, 3, 0), (24, 5, 7), (7, 7, 1)):
        parts = [fold_indices(n, k, f, seed) for f in range(k)]
        vals = [set(v.tolist()) for _, v in parts]
        assert sorted(i for v in vals for i in v) == list(range(n))  # disjoint and complete
        assert max(map(len, vals)) - min(map(len, vals)) <= 1
        for train, val in parts:
            assert set(train.tolist()) == set(range(n)) - set(val.tolist())
            assert list(train) == sorted(train) and list(val) == sorted(val)
    assert [v.tolist() for _, v in (fold_indices(20, 4, f, 3) for f in range(4))] == [
        v.tolist() for _, v in (fold_indices(20, 4, f, 3) for f in range(4))
    ]  # seeded
    assert fold_indices(20, 4, 0, 3)[1].tolist() != fold_indices(20, 4, 0, 4)[1].tolist()
    for args, match in (((5, 1, 0, 0), "2\\+ folds"), ((5, 3, 3, 0), "must be in"), ((2, 3, 0, 0), "fewer folds")):
        with pytest.raises(ConfigError, match=match):
            fold_indices(*args)


def test_train_model_refuses_a_fold_it_cannot_place(registry, data):  # noqa: F811
    gate = build(registry, "pointnet2")
    with pytest.raises(ConfigError, match="trains one gate per fold"):
        gate.fit(data, FOLDS)
    with pytest.raises(ConfigError, match="train.folds is 1"):
        gate.fit(data, TrainConfig(epochs=1, batch_size=8), fold=0)


def test_mean_of_members_is_the_mean_of_the_members_probabilities():
    torch.manual_seed(0)
    nets = [torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(12, 3)) for _ in range(3)]
    x = torch.randn(5, 4, 3)
    expected = np.mean([torch.softmax(n(x), -1).detach().numpy() for n in nets], axis=0)
    got = torch.softmax(MeanOfMembers(nets)(x), -1).detach().numpy()
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-7)
    with pytest.raises(ConfigError, match="2\\+ networks"):
        MeanOfMembers(nets[:1])


@pytest.fixture(scope="module")
def folded(registry, data, tmp_path_factory):  # noqa: F811
    out = tmp_path_factory.mktemp("folds")
    return out, train_folds(lambda: build(registry, "pointnet2"), data, FOLDS, out)


def test_each_member_holds_out_its_fold_and_the_scores_come_from_it(registry, data, folded):  # noqa: F811
    out, result = folded
    ids = data.rates.object_ids
    for f, r in enumerate(result.results):
        assert r.val_ids == [ids[i] for i in fold_indices(len(ids), 3, f, FOLDS.seed)[1]]
        member = load_gate(out / f"fold-{f}" / "gate.pt", registry)
        rows = [ids.index(i) for i in r.val_ids]
        want = member.predict(data.clouds[rows], r.val_ids)
        assert torch.equal(torch.stack([result.out_of_fold[i] for i in r.val_ids]), want)
        assert len(json.loads((out / f"fold-{f}" / "history.json").read_text())) == FOLDS.epochs
    assert sorted(result.out_of_fold) == sorted(ids)  # every object once (none failed everywhere here)


def test_the_averaged_gate_is_the_members_mean_and_survives_a_round_trip(registry, data, folded, tmp_path):  # noqa: F811
    out, result = folded
    members = [load_gate(out / f"fold-{f}" / "gate.pt", registry) for f in range(3)]
    expected = torch.stack([m.predict(data.clouds) for m in members]).mean(dim=0)
    torch.testing.assert_close(result.gate.predict(data.clouds), expected, rtol=1e-5, atol=1e-7)
    assert not torch.allclose(members[0].predict(data.clouds), members[1].predict(data.clouds))  # folds differ
    result.gate.save(tmp_path / "gate.pt")
    assert read_checkpoint(tmp_path / "gate.pt")["members"] == 3
    loaded = load_gate(tmp_path / "gate.pt", registry, experts=list(EXPERTS))
    assert loaded.members == 3 and torch.equal(loaded.predict(data.clouds), result.gate.predict(data.clouds))
    other = build(registry, "pointnet2")
    relabelled = SuccessRates(data.rates.object_ids, ("a", "b", "c"), data.rates.rates)
    other.fit(GateData(relabelled, data.clouds), TrainConfig(epochs=1, batch_size=8))
    with pytest.raises(ConfigError, match="other experts cannot be averaged"):
        type(other).averaged([members[0], other])
    wider = registry.spec("gate", "pointnet2").load()(**{**TINY["pointnet2"], "head": [8]})
    wider.fit(data, TrainConfig(epochs=1, batch_size=8))
    with pytest.raises(ConfigError, match=r"other settings cannot be averaged \(\['head'\] differ\)"):
        type(wider).averaged([members[0], wider])


def test_a_gate_without_a_network_is_refused_before_training(registry, data, tmp_path):  # noqa: F811
    with pytest.raises(ConfigError, match="gate 'centroid' has none"):
        train_folds(lambda: build(registry, "centroid"), data, FOLDS, tmp_path)
    assert not (tmp_path / "fold-0").exists()


def test_ges_train_gate_folds_fits_the_rule_on_the_out_of_fold_scores(tmp_path, capsys, registry):  # noqa: F811
    from ges_core.cli import main

    matrix, infos = _matrix_file(tmp_path)
    (tmp_path / "gate.yaml").write_text(CLI_CONFIG)
    out = tmp_path / "g"
    args = ["train-gate", str(matrix), "--config", str(tmp_path / "gate.yaml"), "--folds", "3", "--out", str(out)]
    assert main(args) == 0
    table = capsys.readouterr().out
    assert "3 folds averaged (kept epochs" in table
    summary = json.loads((out / "summary.json").read_text())
    n_train = sum(o.split == "train" for o in infos)
    assert summary["counts"]["train"] == summary["counts"]["val"] == n_train  # every object scored out of fold
    assert len(summary["kept_epoch"]) == 3 and set(json.loads((out / "history.json").read_text())) == {
        "fold-0", "fold-1", "fold-2"
    }  # fmt: skip
    # the rule, recomputed from the member files: each object's score from the member that held it out
    raw = json.loads(matrix.read_text())
    rates, probs = [], []
    for f in range(3):
        member = load_gate(out / f"fold-{f}" / "gate.pt", registry)
        val_ids = member.train_info["val_ids"]
        clouds = torch.load(out / "clouds-128-0.pt", weights_only=True)
        probs.append(member.predict(torch.stack([clouds[i] for i in val_ids]), val_ids))
        rates += [[raw["cells"][i][e]["paper"] / raw["cells"][i][e]["episodes"] for e in EXPERTS] for i in val_ids]
    rule = fit_pick_rule(EXPERTS, np.asarray(rates), torch.cat(probs), np.asarray(rates))
    assert read_pick_rule(out / "gate.pt") == rule
    assert load_gate(out / "gate.pt", registry).members == 3


class _Killed(Exception):
    pass


def test_a_folds_run_killed_in_its_second_fold_resumes_to_the_same_gate(registry, data, tmp_path):  # noqa: F811
    config = FOLDS.model_copy(update={"epochs": 3})
    straight = train_folds(lambda: build(registry, "pointnet2"), data, config, tmp_path / "a", state_every=1)

    def die(fold, epoch, _result):
        if (fold, epoch) == (1, 2):
            raise _Killed

    with pytest.raises(_Killed):
        train_folds(lambda: build(registry, "pointnet2"), data, config, tmp_path / "b", state_every=1, on_epoch=die)
    assert (tmp_path / "b" / "fold-0" / "gate.pt").is_file() and not (tmp_path / "b" / "fold-2").exists()
    resumed = train_folds(lambda: build(registry, "pointnet2"), data, config, tmp_path / "b", state_every=1,
                          resume=True)  # fmt: skip
    a, b = straight.gate.model.state_dict(), resumed.gate.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert [r.history for r in resumed.results] == [r.history for r in straight.results]

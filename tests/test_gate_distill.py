"""The averaged networks of ``train.folds`` distilled into one (``train.distill``, ``ges train-gate --distill``).

Cross-checks against independent computations: the student's recorded training loss against the KL divergence
recomputed from the averaged gate's and the student's own predictions (and not the one to the success rates), the
stored agreement against the two checkpoint files' predictions, the stored rules against each other, a kill in the
middle of the student's training against a run that never stopped.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_gates import CLI_CONFIG, _matrix_file, build, data, registry  # noqa: F401 - fixtures

from ges_core.config import parse_model
from ges_core.errors import ArrayError, ConfigError
from ges_core.gating import TrainConfig, load_gate
from ges_core.gating.checkpoint import read_pick_rule
from ges_core.gating.data import targets
from ges_core.gating.distill import distill
from ges_core.gating.folds import train_folds
from ges_core.ges_eval.gates import load_gates, parse_gate

FOLDS = TrainConfig(epochs=3, batch_size=8, folds=3, distill=True)


@pytest.fixture(scope="module")
def teacher(registry, data, tmp_path_factory):  # noqa: F811
    out = tmp_path_factory.mktemp("distill")
    return out, train_folds(lambda: build(registry, "pointnet2"), data, FOLDS, out).gate


def _kl(p: np.ndarray, q: np.ndarray) -> float:
    """mean_i sum_j p_ij log(p_ij / q_ij), 0 log 0 = 0: written out, not the training code's kl_loss."""
    p, q = np.asarray(p, dtype=np.float64), np.asarray(q, dtype=np.float64)
    terms = np.where(p > 0, p * (np.log(np.where(p > 0, p, 1.0)) - np.log(q)), 0.0)
    return float(terms.sum(axis=1).mean())


def test_the_student_is_one_network_fitted_to_the_averaged_scores(registry, data, teacher):  # noqa: F811
    out, averaged = teacher
    student, result = distill(lambda: build(registry, "pointnet2"), averaged, data, FOLDS, out)
    assert student.members == 1 and averaged.members == 3
    kept, rates_p = targets(data.rates)
    assert result.train_ids == [data.rates.object_ids[i] for i in kept] and result.val_ids == []
    assert len(result.history) == FOLDS.epochs == len(json.loads((out / "distilled" / "history.json").read_text()))
    own = student.predict(data.clouds[kept]).numpy()
    to_teacher = _kl(averaged.predict(data.clouds[kept]).numpy(), own)
    recorded = result.history[-1]["loss/train_eval"]  # the last epoch is the one kept
    assert recorded == pytest.approx(to_teacher, rel=1e-4, abs=1e-6)
    assert abs(recorded - _kl(rates_p, own)) > 1e-3  # the rates are not what it fitted
    assert student.train_info["distilled_from"]["members"] == 3


class _Killed(Exception):
    pass


def test_a_distillation_killed_mid_way_resumes_to_the_same_network(registry, data, teacher, tmp_path):  # noqa: F811
    _, averaged = teacher
    make = lambda: build(registry, "pointnet2")  # noqa: E731
    straight, _ = distill(make, averaged, data, FOLDS, tmp_path / "a", state_every=1)

    def die(epoch, _result):
        if epoch == 2:
            raise _Killed

    with pytest.raises(_Killed):
        distill(make, averaged, data, FOLDS, tmp_path / "b", state_every=1, on_epoch=die)
    resumed, _ = distill(make, averaged, data, FOLDS, tmp_path / "b", state_every=1, resume=True)
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ConfigError, match="other soft_targets"):  # another teacher: the student, its scores differ
        distill(make, straight, data, FOLDS, tmp_path / "b", state_every=1, resume=True)


def test_soft_targets_must_be_probabilities_of_every_object_and_expert(registry, data):  # noqa: F811
    gate = build(registry, "pointnet2")
    config = TrainConfig(epochs=1, batch_size=8)
    n = len(data.rates.object_ids)
    for soft, match in ((torch.full((n, 2), 0.5), "shape"), (torch.full((n, 3), 0.5), "sum to 1"),
                        (torch.full((n, 3), float("nan")), "finite")):  # fmt: skip
        with pytest.raises(ArrayError, match=match):
            gate.fit(data, config, soft_targets=soft)


def test_the_student_trains_for_distill_epochs_when_set(registry, data, teacher, tmp_path):  # noqa: F811
    """``distill_epochs`` is the student's epoch count alone: the members' config (epochs 3) is unchanged, the
    student's history has 2 rows, and a state written by it resumes (the count is not part of its identity)."""
    _, averaged = teacher
    config = FOLDS.model_copy(update={"distill_epochs": 2})
    student, result = distill(lambda: build(registry, "pointnet2"), averaged, data, config, tmp_path, state_every=1)
    assert len(result.history) == 2 and config.epochs == 3 and config.student_epochs == 2
    assert FOLDS.student_epochs == FOLDS.epochs  # unset: the members' count, as before
    longer = config.model_copy(update={"distill_epochs": 4})  # a finished student extended, as any training
    _, extended = distill(lambda: build(registry, "pointnet2"), averaged, data, longer, tmp_path, resume=True)
    assert len(extended.history) == 4 and json.dumps(extended.history[:2]) == json.dumps(result.history)  # NaN val


def test_distill_without_folds_is_refused_at_the_config():
    with pytest.raises(ConfigError, match="train.distill distils the averaged networks of train.folds >= 2"):
        parse_model(TrainConfig, {"distill": True}, where="train")
    assert parse_model(TrainConfig, {"distill": True, "folds": 2}, where="train").distill


def test_ges_train_gate_distill_stores_the_student_and_the_average(tmp_path, capsys, registry):  # noqa: F811
    from ges_core.cli import main

    matrix, _ = _matrix_file(tmp_path)
    (tmp_path / "gate.yaml").write_text(CLI_CONFIG)
    out = tmp_path / "g"
    args = ["train-gate", str(matrix), "--config", str(tmp_path / "gate.yaml"), "--out", str(out)]
    assert main([*args, "--distill"]) == 1
    assert "folds is 1: set folds (e.g. --folds 5)" in capsys.readouterr().err and not out.exists()
    assert main([*args, "--distill-epochs", "2", "--no-progress"]) == 1  # without --distill it would be ignored
    assert "train.distill_epochs (2) sets the distilled network's epochs, and distill is off" in capsys.readouterr().err
    assert main([*args, "--folds", "3", "--distill", "--distill-epochs", "2", "--no-progress"]) == 0
    assert "distilled into one network" in capsys.readouterr().out
    student, averaged = load_gate(out / "gate.pt", registry), load_gate(out / "averaged.pt", registry)
    assert student.members == 1 and averaged.members == 3
    assert read_pick_rule(out / "gate.pt") == read_pick_rule(out / "averaged.pt")
    summary = json.loads((out / "summary.json").read_text())
    history = json.loads((out / "history.json").read_text())
    assert set(history) == {"fold-0", "fold-1", "fold-2", "distilled"}
    assert [len(history[k]) for k in sorted(history)] == [2, 3, 3, 3]  # the student's 2 epochs, each member's 3
    clouds = torch.load(out / "clouds-128-0.pt", weights_only=True)
    kept = sorted(averaged.train_info["train_ids"])
    x = torch.stack([clouds[i] for i in kept])
    a, b, rule = student.predict(x), averaged.predict(x), read_pick_rule(out / "gate.pt")
    assert summary["distilled"]["train"]["argmax"] == pytest.approx(
        float(np.mean(a.numpy().argmax(1) == b.numpy().argmax(1)))
    )
    described = [
        g.describe()
        for g in load_gates(
            [parse_gate(f"s={out / 'gate.pt'}"), parse_gate(f"a={out / 'averaged.pt'}")], registry, student.experts
        )
    ]
    assert described[0]["networks"] == 1 and described[0]["distilled_from_networks"] == 3
    assert described[1]["networks"] == 3 and "distilled_from_networks" not in described[1]
    experts = list(student.experts)
    assert summary["distilled"]["train"]["pick"] == pytest.approx(
        float(np.mean(rule.choose(a, experts) == rule.choose(b, experts)))
    )

"""The gate's pick rule (ges_core.gating.fallback): the argmax unless it leads the best training expert by a margin
chosen on validation objects. Cross-checked by brute force: the chosen margin's validation success is the best over
every threshold, enumerated here from the leads themselves rather than the module's candidate list."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ges_core.errors import ConfigError
from ges_core.gating.checkpoint import read_checkpoint, read_pick_rule, write_checkpoint, write_pick_rule
from ges_core.gating.fallback import ARGMAX, PickRule, fit_pick_rule

EXPERTS = ("a", "b", "c")


def test_argmax_rule_is_the_argmax_and_a_fallback_rule_keeps_only_clear_leads():
    p = torch.tensor([[0.2, 0.5, 0.3], [0.45, 0.1, 0.45], [0.1, 0.2, 0.7], [0.34, 0.33, 0.33]])
    assert ARGMAX.choose(p, EXPERTS).tolist() == p.argmax(dim=1).tolist()
    rule = PickRule("a", 0.3)
    # leads over 'a': 0.3 (not more than 0.3), 0 (tie), 0.6, 0 (a is the top)
    assert rule.choose(p, EXPERTS).tolist() == [0, 0, 2, 0]
    assert PickRule("a", 0.0).choose(p, EXPERTS).tolist() == [1, 0, 2, 0]  # margin 0: the argmax but a tie goes to 'a'
    assert PickRule("c", 1.0).choose(p, EXPERTS).tolist() == [2, 2, 2, 2]
    with pytest.raises(ConfigError, match="'z' is not one of the gate's"):
        PickRule("z", 0.1).choose(p, EXPERTS)
    with pytest.raises(ConfigError, match="margin"):
        PickRule("a", float("nan"))


def _val_success(rule: PickRule, probs: np.ndarray, rates: np.ndarray) -> float:
    pick = rule.choose(probs, EXPERTS)
    return float(rates[np.arange(len(rates)), pick].mean())


@pytest.mark.parametrize("seed", range(40))
def test_the_margin_is_the_best_on_validation_by_brute_force(seed):
    rng = np.random.default_rng(seed)
    n_train, n_val = int(rng.integers(3, 12)), int(rng.integers(1, 10))
    train = rng.integers(0, 5, size=(n_train, 3)) / 4
    val = rng.integers(0, 5, size=(n_val, 3)) / 4
    probs = rng.dirichlet(np.ones(3), size=n_val)
    rule = fit_pick_rule(EXPERTS, train, probs, val)
    assert rule.fallback == EXPERTS[int(np.argmax(train.mean(axis=0)))]  # the best training expert, first of equals
    # every threshold pattern: 0, each lead over the fallback just below and just above, and past them all
    f = EXPERTS.index(rule.fallback)
    leads = probs.max(axis=1) - probs[:, f]
    margins = sorted({0.0, *(max(0.0, g + d) for g in leads for d in (-1e-9, 1e-9))})
    success = [_val_success(PickRule(rule.fallback, m), probs, val) for m in margins]
    best = max(success)
    assert _val_success(rule, probs, val) == pytest.approx(best, abs=1e-12)
    # the largest margin of the best: the rule picks as the largest threshold that reaches the best does
    largest = max(m for m, s in zip(margins, success, strict=True) if s == pytest.approx(best, abs=1e-12))
    assert (PickRule(rule.fallback, largest).choose(probs, EXPERTS) == rule.choose(probs, EXPERTS)).all()


def test_a_gate_that_gains_nothing_on_validation_always_falls_back():
    train = np.array([[1.0, 0.75, 0.5], [1.0, 1.0, 0.5]])
    val = np.array([[1.0, 1.0, 1.0], [0.75, 0.75, 0.75]])  # the experts tie on every held-out object
    probs = np.array([[0.1, 0.8, 0.1], [0.2, 0.2, 0.6]])  # the gate leads elsewhere: noise
    rule = fit_pick_rule(EXPERTS, train, probs, val)
    assert (rule.fallback, rule.margin) == ("a", 1.0)
    assert rule.choose(np.array([[0.0, 0.0, 1.0]]), EXPERTS).tolist() == [0]  # even a certain gate on a new object
    assert "always a" in rule.describe()


def test_a_gate_that_gains_on_validation_keeps_its_leads():
    train = np.array([[1.0, 0.5], [0.75, 0.5]])
    val = np.array([[0.0, 1.0], [0.25, 1.0], [1.0, 1.0]])  # 'b' wins the first two held-out objects
    probs = np.array([[0.1, 0.9], [0.3, 0.7], [0.45, 0.55]])
    rule = fit_pick_rule(("a", "b"), train, probs, val)
    assert rule.fallback == "a" and rule.margin == pytest.approx(0.1)  # the third lead (0.1) is not needed
    assert rule.choose(probs, ("a", "b")).tolist() == [1, 1, 0]
    assert "100.0 % against 100.0 % with the argmax and 41.7 % with the fallback alone" in rule.how


def test_without_validation_objects_the_margin_is_zero():
    rule = fit_pick_rule(EXPERTS, np.array([[0.0, 1.0, 0.5]]), np.zeros((0, 3)), np.zeros((0, 3)))
    assert (rule.fallback, rule.margin) == ("b", 0.0) and "no validation objects" in rule.how


def test_the_rule_is_stored_in_any_gate_checkpoint(tmp_path):
    path = tmp_path / "gate.pt"
    state = {"x": torch.ones(2)}
    write_checkpoint(path, {"gate": "centroid", "experts": list(EXPERTS), "settings": {}, "state": state})
    assert read_pick_rule(path) == ARGMAX  # written before rules: the paper's argmax
    rule = PickRule("b", 0.25, "chosen here")
    write_pick_rule(path, rule)
    assert read_pick_rule(path) == rule
    data = read_checkpoint(path)
    assert data["experts"] == list(EXPERTS) and torch.equal(data["state"]["x"], torch.ones(2))  # the rest untouched
    assert PickRule.from_json(rule.to_json()) == rule


def test_a_damaged_rule_is_a_clear_error_naming_the_file(tmp_path):
    path = tmp_path / "gate.pt"
    write_checkpoint(path, {"gate": "centroid", "experts": list(EXPERTS), "settings": {}, "state": {},
                            "pick": {"fallback": "a", "margin": "wide"}})  # fmt: skip
    with pytest.raises(ConfigError, match=r"gate.pt: its pick rule .* --gate-argmax"):
        read_pick_rule(path)

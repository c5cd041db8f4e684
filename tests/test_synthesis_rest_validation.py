"""The resting check in every validating engine: an object that does not stay at rest in a validating engine
other than the refinement's gets that engine's verdict ``unstable_rest`` (with the drift in the record's
errors) instead of a judged grasp; the other engines' verdicts are unchanged.

The check itself (``check_rest``: real SAPIEN and PyBullet, an egg on its tip) is tested in
``tests/test_synthesis_rest.py``; here the pipeline's wiring, with the real engines running everything else and
the PyBullet check made to report a drift.
"""

from __future__ import annotations

import pytest

from ges_core.dataset import open_dataset
from ges_core.errors import SynthesisError
from ges_core.synthesis import SynthesisConfig, run_synthesis
from ges_core.synthesis.run import worker

OBJECT = "procedural/box/000"
CONFIG = SynthesisConfig(refine_sim="sapien", validate_sims=("sapien", "pybullet"), robust={"enabled": False})


def _record(out):
    (record,) = list(open_dataset(out))
    return record


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    out = tmp_path_factory.mktemp("plain") / "ds"
    run_synthesis([OBJECT], ["allegro"], CONFIG, out)
    return _record(out)


def test_a_drift_in_another_validating_engine_is_its_verdict(plain, tmp_path, monkeypatch):
    calls = []
    real = worker.check_rest

    def drifting_in_pybullet(sim, hand, obj, config):
        calls.append(sim.name)
        if sim.name == "pybullet":
            raise SynthesisError(f"object '{obj.object_id}' does not stay at rest in pybullet", reason="unstable_rest")
        return real(sim, hand, obj, config)

    monkeypatch.setattr(worker, "check_rest", drifting_in_pybullet)
    record = _record(run_synthesis([OBJECT], ["allegro"], CONFIG, tmp_path / "ds").root)
    assert calls == ["sapien", "pybullet"]  # each engine once per object, the refining one before refinement
    assert plain.validations["pybullet"].reason != "unstable_rest"
    assert record.validations["pybullet"].reason == "unstable_rest" and not record.validations["pybullet"].success
    assert "does not stay at rest in pybullet" in record.errors["validation_pybullet"]
    assert record.validations["sapien"].success == plain.validations["sapien"].success
    assert record.validations["sapien"].reason == plain.validations["sapien"].reason
    main, before = record.steps["validation"], plain.steps["validation"]
    assert (main.ok, main.reason) == (before.ok, before.reason)  # the primary engine's verdict stands

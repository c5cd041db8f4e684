"""The grasp dataset: round trip, resume after a kill, validation of damaged records, config checks, info."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from ges_core import cli
from ges_core.contact import ContactSet
from ges_core.dataset import (
    NOT_RUN,
    STEPS,
    TOTAL_STEPS,
    AttemptVerdict,
    DatasetWriter,
    GraspRecord,
    HandPose,
    Quality,
    RefinementInfo,
    SimVerdict,
    StepOutcome,
    TrialVerdict,
    open_dataset,
    record_relpath,
    software_versions,
    summarize,
    validate_dataset,
)
from ges_core.dataset.checks import record_problems
from ges_core.dataset.layout import DATASET_VERSION, config_hash, normalize_config
from ges_core.dataset.record import (
    RECORD_VERSION,
    raw_to_bytes,
    read_raw,
    record_from_bytes,
    record_from_raw,
    record_to_bytes,
    record_to_raw,
)
from ges_core.dataset.record_v1 import upgraded
from ges_core.dataset.store import load_record
from ges_core.dataset.timing import record_timing
from ges_core.errors import AssetError, ConfigError
from ges_core.paths import atomic_write_bytes

DATASET_V1 = Path(__file__).parent / "data" / "dataset_v1"
"""Four records written by the version-1 code (three of ``ges demo``, one failed contact step of ``ges synth``)."""
CONFIG = {"hands": ["shadow", "allegro"], "sim": "sapien", "seed": 3, "refine": {"gamma": 2.5}}
JOINTS = {"shadow": tuple(f"rh_J{i}" for i in range(24)), "allegro": tuple(f"joint_{i}.0" for i in range(16))}


def _unit(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    v = rng.normal(size=shape)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _pose(rng: np.random.Generator, k: int) -> HandPose:
    return HandPose(np.concatenate([rng.normal(size=3) * 0.1, _unit(rng, (4,))]), rng.uniform(-1, 1, k))


def make_record(object_id: str, hand: str = "shadow", *, fail_at: str | None = None, seed: int = 0, **kw):
    """A record with random but valid content; ``fail_at`` makes that step fail and later ones skipped."""
    rng = np.random.default_rng(zlib.crc32(f"{object_id} {hand} {seed}".encode()))  # same in every process
    k = len(JOINTS[hand])
    steps, failed = {}, False
    for name in STEPS:
        if failed:
            steps[name] = StepOutcome.skipped()
        elif name == fail_at:
            reason = "mass_x2" if name == "robust" else f"{name}_failed"
            steps[name], failed = StepOutcome.failed(reason, 0.01), True
        else:
            steps[name] = StepOutcome(ok=True, seconds=float(rng.uniform(0.01, 0.5)))
    has_contacts, has_grasp = fail_at != "contacts", fail_at not in ("contacts", "retargeting")
    contacts = ContactSet(rng.normal(size=(5, 3)) * 0.03, _unit(rng, (5, 3)), object_id) if has_contacts else None
    fields = dict(
        object_id=object_id,
        category=object_id.split("/")[1],
        split="train",
        hand=hand,
        simulator="sapien",
        joint_names=JOINTS[hand],
        steps=steps,
        contacts=contacts,
        strategy="vertical" if has_contacts else None,
        approach=_unit(rng, (3,)) if has_contacts else None,
        grasp=_pose(rng, k) if has_grasp else None,
        grasp_stage="refinement" if has_grasp else "",
        pregrasp=_pose(rng, k) if has_grasp else None,
        quality=Quality(force_closure=0.12, retarget_residual=0.0008, max_penetration=0.001, table_contact=False),
        validation_flags={"lifted": fail_at is None, "held": fail_at is None},
        versions=software_versions("sapien"),
        seed=seed,
        **_notes(hand, fail_at),
        extra={"operator": "test"},
    )
    return GraspRecord(**(fields | kw))


def _notes(hand: str, fail_at: str | None) -> dict:
    """The typed Stage 1 notes of a record failing at ``fail_at`` (None: passing)."""
    refined = fail_at not in ("contacts", "retargeting")
    validated = refined and fail_at != "refinement"
    held = fail_at in (None, "robust")  # the nominal trial
    trials = (
        TrialVerdict(name="limits", success=True, reason="success"),
        TrialVerdict(name="mass_x2", success=fail_at is None, reason="success" if fail_at is None else "dropped"),
    )
    verdict = SimVerdict(success=held, reason="success" if held else "dropped",
                         flags={"lifted": True, "held": held}, seconds=0.2,
                         trials=trials if held else (), robustness=(1.0 if fail_at is None else 0.5) if held else None,
                         robust_seconds=0.4 if held else 0.0)  # fmt: skip
    attempt = AttemptVerdict(
        refinement="ok",
        validation="ok" if held else "dropped",
        robust="ok" if fail_at is None else ("mass_x2" if held else "skipped"),
        robustness=verdict.robustness,
    )
    return {
        "symmetric": None if fail_at == "contacts" else False,
        "attempt": 0 if held else None,
        "attempts": (attempt,) if refined else (),
        "refinement": RefinementInfo(
            frozen=["thumb", "index"],
            touching_fingers=["thumb", "index", "middle"],
            object_shift=0.001,
            object_turn_deg=0.5,
        )
        if refined
        else None,  # fmt: skip
        "validations": {"sapien": verdict, "pybullet": verdict} if validated else {},
        "errors": {fail_at: f"{fail_at} went wrong"} if fail_at in ("contacts", "retargeting") else {},
        "setup_seconds": {"sapien": 0.03} if refined else {},
        "picture": f"pictures/{hand}.png",
    }


def assert_same(a: GraspRecord, b: GraspRecord, *, times: bool = True) -> None:
    """Field-by-field equality, arrays exactly (float64 storage loses nothing) except the normals, which
    ContactSet normalizes again when it is built (a unit vector may move by one ulp); the run-config hash the
    writer stamps is left out, the times compared when ``times``."""
    meta_a, arrays_a = record_to_raw(replace(a, run_config_hash=None))
    meta_b, arrays_b = record_to_raw(replace(b, run_config_hash=None))
    assert meta_a == meta_b
    if times:
        assert record_timing(a) == record_timing(b)
    assert sorted(arrays_a) == sorted(arrays_b)
    for name in arrays_a:
        atol = 1e-15 if name == "contact_normals" else 0.0
        np.testing.assert_allclose(arrays_a[name], arrays_b[name], rtol=0, atol=atol)


RECORDS = [
    ("procedural/box/000", "shadow", None),
    ("procedural/mug/001", "shadow", "retargeting"),
    ("procedural/can/002", "allegro", "validation"),
    ("pybullet/duck/000", "allegro", None),
]


@pytest.fixture
def records() -> list[GraspRecord]:
    return [make_record(o, h, fail_at=f) for o, h, f in RECORDS]


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


# --- round trip ---------------------------------------------------------------------------------


def test_round_trip_keeps_every_field(tmp_path, records):
    writer = DatasetWriter(tmp_path / "ds", CONFIG)
    for r in records:
        writer.add(r)
    ds = open_dataset(tmp_path / "ds")
    assert len(ds) == 4 and ds.run_config == normalize_config(CONFIG)
    for r in records:
        stored = ds.get(r.object_id, r.hand)
        assert_same(stored, r)
        assert stored.run_config_hash == config_hash(normalize_config(CONFIG)) == writer.config_hash
    assert [e["object_id"] for e in ds.entries] == sorted(o for o, h, _ in RECORDS if h == "allegro") + sorted(
        o for o, h, _ in RECORDS if h == "shadow"
    )
    assert [r.object_id for r in ds.records(hand="shadow", split="train")] == [
        "procedural/box/000",
        "procedural/mug/001",
    ]


def test_record_file_reads_with_plain_numpy_and_json(tmp_path, records):
    """A later stage needs neither the hand nor the simulator plugin, nor this package's reader."""
    writer = DatasetWriter(tmp_path / "ds", CONFIG)
    path = writer.add(records[2])
    with np.load(path, allow_pickle=False) as npz:
        meta = json.loads(str(npz["record_json"]))
        q, normals = npz["q"], npz["contact_normals"]
    assert meta["hand"] == "allegro" and len(meta["joint_names"]) == q.shape[0] == 16
    assert meta["steps"]["validation"] == {"ok": False, "reason": "validation_failed"}  # times: the timing file
    timing = json.loads(path.with_name(path.name.replace(".npz", ".timing.json")).read_text())
    assert timing["steps"]["validation"] == 0.01 and timing["validations"]["sapien"] == 0.2
    np.testing.assert_array_equal(q, records[2].grasp.q)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    assert meta["versions"]["ges"] and meta["versions"]["sapien"] != "missing"


def test_record_properties():
    ok, failed = make_record("procedural/box/0"), make_record("procedural/box/0", fail_at="refinement")
    assert ok.success and ok.failed_step is None
    assert not failed.success and failed.failed_step == "refinement"
    assert failed.steps["validation"].reason == "skipped" and not failed.steps["validation"].attempted
    no_validation = make_record("procedural/box/0", steps=dict(ok.steps, validation=StepOutcome.failed(NOT_RUN)))
    assert no_validation.success and no_validation.failed_step is None
    assert ok.total_seconds == pytest.approx(sum(ok.steps[s].seconds for s in TOTAL_STEPS))  # robust apart


def test_numpy_scalars_are_stored_as_plain_json(tmp_path):
    record = make_record(
        "procedural/box/0", quality=Quality(force_closure=np.float32(0.5), table_contact=np.bool_(True))
    )
    again = record_from_bytes(record_to_bytes(record))
    assert again.quality.force_closure == pytest.approx(0.5) and again.quality.table_contact is True


def test_file_names_are_unique_and_readable():
    a, b = record_relpath("procedural/mug/001", "shadow"), record_relpath("procedural__mug/001", "shadow")
    assert a.startswith("records/shadow/procedural__mug__001-") and a.endswith(".npz")
    assert a != b and record_relpath("procedural/mug/001", "allegro") != a


# --- writer errors ------------------------------------------------------------------------------


def test_add_rejects_duplicates_unless_overwrite(tmp_path, records):
    writer = DatasetWriter(tmp_path / "ds", CONFIG)
    writer.add(records[0])
    with pytest.raises(ValueError, match=r"already holds the record of object 'procedural/box/000' with hand 'shadow'"):
        writer.add(records[0])
    changed = make_record("procedural/box/000", seed=7)
    writer.add(changed, overwrite=True)
    assert_same(open_dataset(tmp_path / "ds").get("procedural/box/000", "shadow"), changed)


def test_add_rejects_an_invalid_record_and_writes_nothing(tmp_path):
    writer = DatasetWriter(tmp_path / "ds", CONFIG)
    bad = make_record("procedural/box/000", joint_names=JOINTS["shadow"][:-1])
    with pytest.raises(ValueError, match=r"is invalid: array pregrasp_q: shape \(24,\), expected \(23,\)"):
        writer.add(bad)
    assert not writer.has("procedural/box/000", "shadow") and not list((tmp_path / "ds").rglob("*.npz"))


def test_config_mismatch_fails_clearly_or_is_allowed(tmp_path, records):
    DatasetWriter(tmp_path / "ds", CONFIG).add(records[0])
    other = dict(CONFIG, refine={"gamma": 3.0})
    with pytest.raises(ConfigError, match=r"another run config \(refine.gamma: 2.5 -> 3.0\)") as info:
        DatasetWriter(tmp_path / "ds", other)
    assert "allow_config_change=True" in str(info.value) and info.value.problems == ["refine.gamma: 2.5 -> 3.0"]
    writer = DatasetWriter(tmp_path / "ds", other, allow_config_change=True)
    assert writer.has("procedural/box/000", "shadow")
    manifest = json.loads((tmp_path / "ds" / "manifest.json").read_text())
    assert manifest["run_config"]["refine"]["gamma"] == 3.0
    assert manifest["config_history"][0]["run_config"]["refine"]["gamma"] == 2.5


def test_a_refused_resume_names_the_settings_the_folder_predates_and_how_to_reproduce_them(tmp_path, records):
    """``absent_means``: a folder written before ``refine.cap`` existed ran as cap=null; refused at the new default
    with that said, it resumes when the run asks for null (which the stored config leaves out, as before)."""
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        writer.add(records[0])
    newer = dict(CONFIG, refine={**CONFIG["refine"], "cap": 0.005})
    with pytest.raises(ConfigError) as info:
        DatasetWriter(tmp_path / "ds", newer, absent_means={"refine.cap": None, "other.key": 1})
    message = str(info.value)
    assert "refine.cap: '<absent>' -> 0.005" in message and "predates refine.cap: it ran as refine.cap=null" in message
    assert "ges synth: -o refine.cap=null; ges demo: -o synthesis.refine.cap=null resumes it as it was" in message
    assert "other.key" not in message  # only what differs
    with pytest.raises(ConfigError) as plain:  # a difference that is no late setting: no such sentence
        DatasetWriter(tmp_path / "ds", dict(CONFIG, refine={"gamma": 3.0}), absent_means={"refine.cap": None})
    assert "predates" not in str(plain.value)
    with DatasetWriter(tmp_path / "ds", CONFIG, absent_means={"refine.cap": None}) as writer:  # null: left out
        assert writer.has("procedural/box/000", "shadow")


def test_same_config_in_another_form_is_accepted(tmp_path):
    from dataclasses import dataclass

    @dataclass
    class Cfg:
        hands: tuple = ("shadow",)
        out: Path = Path("/tmp/x")

    DatasetWriter(tmp_path / "ds", Cfg())
    DatasetWriter(tmp_path / "ds", {"hands": ["shadow"], "out": "/tmp/x"})  # tuple -> list, Path -> str
    with pytest.raises(TypeError, match="run_config must be a dict, a pydantic model or a dataclass, got int"):
        DatasetWriter(tmp_path / "other", 3)


def test_writer_refuses_a_foreign_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(AssetError, match="is not empty and holds no manifest.json: it is not a grasp dataset"):
        DatasetWriter(tmp_path, CONFIG)


def test_reader_errors_name_the_problem(tmp_path, records):
    with pytest.raises(AssetError, match="is not a grasp dataset: it has no manifest.json"):
        open_dataset(tmp_path)
    (tmp_path / "manifest.json").write_text("{broken")
    with pytest.raises(AssetError, match="cannot read .*manifest.json.*rebuilds the index from the record files"):
        open_dataset(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "something_else"}))
    with pytest.raises(AssetError, match="format 'something_else', expected 'ges.contactgrasp_dataset'"):
        open_dataset(tmp_path)
    (tmp_path / "manifest.json").write_text(json.dumps({"format": "ges.contactgrasp_dataset", "version": 99}))
    with pytest.raises(AssetError, match="dataset version 99 is not supported"):
        open_dataset(tmp_path)


def test_damaged_record_is_left_out_raises_on_read_and_missing_key_is_a_keyerror(tmp_path, records):
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        path = writer.add(records[0])
    path.write_bytes(path.read_bytes()[:100])
    ds = open_dataset(tmp_path / "ds")
    file = path.relative_to(tmp_path / "ds").as_posix()
    assert list(ds) == [] and ds.damaged == (file,)
    assert any(n.startswith(f"{file} cannot be used (left out): unreadable record") for n in ds.notes)
    with pytest.raises(AssetError, match=r"cannot read grasp record .*Run 'ges dataset validate"):
        load_record(tmp_path / "ds", file)
    with pytest.raises(KeyError, match="holds no record of object 'x' with hand 'shadow'"):
        ds.get("x", "shadow")
    with pytest.raises(AssetError, match="cannot read grasp record"):
        load_record(tmp_path / "ds", "records/none.npz")


# --- resume after a kill ------------------------------------------------------------------------


def test_resume_after_a_kill_between_record_and_manifest(tmp_path, records, monkeypatch):
    """The record file is written, the run dies before the manifest names it: nothing is lost."""
    import ges_core.dataset.store as store

    root = tmp_path / "ds"
    writer = DatasetWriter(root, CONFIG, manifest_interval=0)
    writer.add(records[0])
    real = store.write_manifest

    def die(*args, **kwargs):
        raise KeyboardInterrupt  # the kill, right after the record's atomic write

    monkeypatch.setattr(store, "write_manifest", die)
    with pytest.raises(KeyboardInterrupt):
        writer.add(records[1])
    monkeypatch.setattr(store, "write_manifest", real)
    del writer  # the killed run's lock goes with it
    listed = [e["object_id"] for e in json.loads((root / "manifest.json").read_text())["records"]]
    assert listed == ["procedural/box/000"]
    ds = open_dataset(root)  # the reader adopts the unlisted file in memory
    assert len(ds) == 2 and ds.unlisted == (record_relpath("procedural/mug/001", "shadow"),)
    assert any("not listed in manifest.json" in p for p in validate_dataset(root))
    resumed = DatasetWriter(root, CONFIG)
    assert resumed.has("procedural/mug/001", "shadow") and any("adopted" in m for m in resumed.recovered)
    for r in records:
        if not resumed.has(*r.key):
            resumed.add(r)
    resumed.close()
    assert validate_dataset(root) == []
    for r in records:
        assert_same(open_dataset(root).get(*r.key), r)


def test_damaged_unlisted_record_is_left_out_by_the_reader_and_moved_aside_by_the_writer(tmp_path, records, capsys):
    root = tmp_path / "ds"
    writer = DatasetWriter(root, CONFIG, manifest_interval=3600)
    good, bad = writer.add(records[0]), writer.add(records[1])  # neither listed yet
    del writer  # killed
    bad.write_bytes(bad.read_bytes()[:50])
    rel = bad.relative_to(root).as_posix()
    ds = open_dataset(root)
    assert [e["object_id"] for e in ds.entries] == ["procedural/box/000"] and ds.damaged == (rel,)
    code, out, _ = run_cli(capsys, "dataset", "info", str(root))
    assert code == 0 and f"{rel} cannot be used (left out): unreadable record" in out
    writer = DatasetWriter(root, CONFIG)
    assert not writer.has(*records[1].key) and writer.has(*records[0].key) and good.exists() and not bad.exists()
    assert (root / ".damaged" / rel).is_file() and not (root / ".damaged" / rel).with_suffix("").exists()
    assert any(n.startswith(f"moved {rel} to .damaged/{rel}: unreadable record") for n in writer.recovered)


def test_manifest_interval_batches_index_writes_without_losing_records(tmp_path, records):
    root = tmp_path / "ds"
    writer = DatasetWriter(root, CONFIG, manifest_interval=3600)
    for r in records:
        writer.add(r)
    assert json.loads((root / "manifest.json").read_text())["records"] == []  # as if killed now
    del writer
    assert len(open_dataset(root)) == 4 and len(DatasetWriter(root, CONFIG)) == 4
    with DatasetWriter(tmp_path / "ds2", CONFIG, manifest_interval=3600) as writer:
        for r in records:
            writer.add(r)
    assert len(json.loads((tmp_path / "ds2" / "manifest.json").read_text())["records"]) == 4


def test_leftover_temp_file_is_reported_then_removed(tmp_path, records):
    root = tmp_path / "ds"
    with DatasetWriter(root, CONFIG) as writer:
        writer.add(records[0])
    temp = root / "records" / "shadow" / ".procedural__mug__001-0.npz.abc123.tmp"
    temp.write_bytes(b"PK\x03\x04 half a zip")
    assert validate_dataset(root) == [
        "records/shadow/.procedural__mug__001-0.npz.abc123.tmp: leftover temporary file from an interrupted write "
        "(the writer removes it)"
    ]
    assert len(open_dataset(root)) == 1
    writer = DatasetWriter(root, CONFIG)
    assert not temp.exists() and len(writer) == 1 and "interrupted write" in writer.recovered[0]


def test_listed_but_missing_file_is_generated_again(tmp_path, records):
    root = tmp_path / "ds"
    with DatasetWriter(root, CONFIG) as writer:
        paths = [writer.add(r) for r in records[:2]]
    paths[1].unlink()
    timing = record_relpath("procedural/mug/001", "shadow").replace(".npz", ".timing.json")
    assert validate_dataset(root) == [
        f"manifest.json: lists {record_relpath('procedural/mug/001', 'shadow')}, which does not exist",
        f"{timing}: timing file whose record is not there (the writer removes it)",
    ]
    ds = open_dataset(root)
    assert len(ds) == 1 and ds.missing and "missing" in summarize(ds).format()
    resumed = DatasetWriter(root, CONFIG)
    assert not resumed.has("procedural/mug/001", "shadow") and "will be generated again" in resumed.recovered[0]
    assert resumed.recovered[1] == f"removed {timing}: timing file whose record is gone"
    assert not (root / timing).exists()


_KILL_SCRIPT = """
import os, signal, sys
sys.path.insert(0, {tests!r})
import test_dataset as t
from ges_core.dataset import DatasetWriter
calls = [0]
real_replace = os.replace
def replace(src, dst):
    calls[0] += 1
    if calls[0] == {kill_at}:
        os.kill(os.getpid(), signal.SIGKILL)  # dies with the temp file written, not renamed
    real_replace(src, dst)
os.replace = replace
writer = DatasetWriter({root!r}, t.CONFIG, manifest_interval=0)
for i in range(8):
    if not writer.has(f"procedural/box/{{i:03d}}", "shadow"):
        writer.add(t.make_record(f"procedural/box/{{i:03d}}", "shadow", seed=i))
"""


@pytest.mark.parametrize(
    ("kill_at", "survivors"), [(5, 1), (6, 2), (7, 2)]
)  # renames: 1 manifest, then record, its timing file, manifest, ...: 5 = a record, 6 = a timing file, 7 = a manifest
def test_resume_after_sigkill_loses_nothing(tmp_path, kill_at, survivors):
    root = tmp_path / "ds"
    script = _KILL_SCRIPT.format(tests=str(Path(__file__).parent), kill_at=kill_at, root=str(root))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert list(root.rglob(".*.tmp")) and (root / ".lock").exists()  # the kill left a temporary file and its lock
    survived = {e["object_id"] for e in open_dataset(root).entries}
    assert len(survived) == survivors  # every record whose file was renamed into place
    with DatasetWriter(root, CONFIG) as writer:
        assert writer.recovered[0].startswith(f"took over {root / '.lock'}: it was left by pid ")
        for i in range(8):
            if not writer.has(f"procedural/box/{i:03d}", "shadow"):
                writer.add(make_record(f"procedural/box/{i:03d}", "shadow", seed=i))
    assert validate_dataset(root) == [] and not list(root.rglob(".*.tmp")) and not (root / ".lock").exists()
    untimed = "procedural/box/001" if kill_at == 6 else None  # whole record, its times lost with the kill
    for i in range(8):
        expected = make_record(f"procedural/box/{i:03d}", "shadow", seed=i)
        stored = open_dataset(root).get(expected.object_id, "shadow")
        assert_same(stored, expected, times=expected.object_id != untimed)
        assert (stored.total_seconds is None) == (expected.object_id == untimed)


# --- validation of damaged records --------------------------------------------------------------


def _steps(meta, **changes):
    for name, value in changes.items():
        meta["steps"][name] = value


def _drop(arrays, *names):
    for name in names:
        arrays.pop(name)


# (mutation of a valid, fully successful Shadow record's scalars and arrays, the expected problem)
CORRUPTIONS = {
    "normal": (
        lambda m, a: a.update(contact_normals=a["contact_normals"] * 1.01),
        "array contact_normals: vector norm differs from 1 by 1.00e-02",
    ),
    "quaternion": (
        lambda m, a: a["wrist_pose"].__setitem__(slice(3, 7), 2 * a["wrist_pose"][3:]),
        "array wrist_pose: quaternion norm differs from 1 by 1.00e+00",
    ),
    "joint_count": (
        lambda m, a: a.update(q=a["q"][:-1]),
        "array q: shape (23,), expected (24,) (one value per joint name)",
    ),
    "nan": (lambda m, a: a["approach"].__setitem__(0, np.nan), "array approach: holds NaN or inf"),
    "dtype": (lambda m, a: a.update(q=np.zeros(24, dtype=np.int64)), "array q: dtype int64, expected float64"),
    "unknown_array": (lambda m, a: a.update(extra_thing=np.zeros(2)), "array extra_thing: unknown array name"),
    "half_pose": (
        lambda m, a: _drop(a, "pregrasp_q"),
        "arrays pregrasp_wrist_pose and pregrasp_q: one is stored without the other",
    ),
    "ok_with_reason": (
        lambda m, a: _steps(m, contacts={"ok": True, "reason": "x"}),
        "steps.contacts: ok=True with reason 'x' (a success has no reason, a failure has one)",
    ),
    "failure_without_reason": (
        lambda m, a: _steps(m, validation={"ok": False, "reason": ""}),
        "steps.validation: ok=False with reason ''",
    ),
    "not_skipped": (
        lambda m, a: _steps(m, retargeting={"ok": False, "reason": "r"}),
        "steps.refinement: is 'ok' but the earlier step retargeting failed",
    ),
    "skipped_after_success": (
        lambda m, a: _steps(m, validation={"ok": False, "reason": "skipped"}),
        "steps.validation: is 'skipped' but no earlier step failed",
    ),
    "missing_step": (
        lambda m, a: m["steps"].pop("validation"),
        "steps: must hold exactly ['contacts', 'retargeting', 'refinement', 'validation', 'robust']",
    ),
    "step_shape": (lambda m, a: _steps(m, contacts=3), "steps.contacts: must be {ok, reason} (its time lives"),
    "step_types": (
        lambda m, a: _steps(m, contacts={"ok": 1, "reason": ""}),
        "steps.contacts: ok must be a bool and reason a string",
    ),
    "time_inside": (
        lambda m, a: _steps(m, contacts={"ok": True, "reason": "", "seconds": 0.1}),
        "steps.contacts: must be {ok, reason} (its time lives in the timing file)",
    ),
    "empty_hand": (lambda m, a: m.update(hand=""), "hand: must be a non-empty string, got ''"),
    "strategy": (
        lambda m, a: m.update(strategy="diagonal"),
        "strategy: 'diagonal' is not one of [None, 'horizontal', 'vertical']",
    ),
    "duplicate_joints": (
        lambda m, a: m["joint_names"].__setitem__(1, m["joint_names"][0]),
        "joint_names: duplicated ['rh_J0']",
    ),
    "joint_names_type": (
        lambda m, a: m.update(joint_names="rh_J0"),
        "joint_names: must be a list of non-empty strings",
    ),
    "penetration": (
        lambda m, a: m["quality"].update(max_penetration=-0.1),
        "quality.max_penetration: must be a finite number >= 0 or null, got -0.1",
    ),
    "table_contact": (
        lambda m, a: m["quality"].update(table_contact="yes"),
        "quality.table_contact: must be true, false or null, got 'yes'",
    ),
    "quality_key": (lambda m, a: m["quality"].update(grip=1.0), "quality: must be an object with keys among"),
    "versions": (lambda m, a: m["versions"].update(torch=2), "versions: must map package names to version strings"),
    "flags": (lambda m, a: m["validation_flags"].update(held="yes"), "validation_flags: must map names to true/false"),
    "seed": (lambda m, a: m.update(seed="3"), "seed: must be an integer, got '3'"),
    "extra": (lambda m, a: m.update(extra=[]), "extra: must be an object, got []"),
    "note_missing": (
        lambda m, a: m.pop("picture"),
        "picture: missing (a version-2+ record stores it, null or empty when there is none)",
    ),
    "symmetric": (lambda m, a: m.update(symmetric="no"), "symmetric: must be true, false or null, got 'no'"),
    "errors": (lambda m, a: m["errors"].update(contacts=3), "errors: must be an object of messages"),
    "config_hash": (
        lambda m, a: m.update(run_config_hash="xyz"),
        "run_config_hash: must be 16 hex digits or null, got 'xyz'",
    ),
    "setup_seconds_inside": (
        lambda m, a: m.update(setup_seconds={"sapien": 0.1}),
        "setup_seconds: not a key of a version-3 record",
    ),
    "attempts": (lambda m, a: m["attempts"].append({"refinement": "ok"}), "attempts: must be a list of"),
    "attempt": (
        lambda m, a: m.update(attempt=1),
        "attempt: must be null or an index into the 1 attempts, got 1",
    ),
    "refinement_keys": (lambda m, a: m["refinement"].pop("frozen"), "refinement: must be null or {frozen,"),
    "refinement_shift": (
        lambda m, a: m["refinement"].update(object_shift=float("nan")),
        "refinement.object_shift: must be a finite number >= 0, got nan",
    ),
    "refinement_fingers": (
        lambda m, a: m["refinement"].update(frozen="thumb"),
        "refinement.frozen: must be a list of finger names",
    ),
    "validations": (lambda m, a: m.update(validations=[]), "validations: must map simulators to verdicts"),
    "verdict_keys": (lambda m, a: m["validations"]["sapien"].pop("flags"), "validations.sapien: must be {flags,"),
    "verdict_types": (
        lambda m, a: m["validations"]["sapien"].update(success="yes"),
        "validations.sapien: success must be a bool and reason a string",
    ),
    "verdict_flags": (
        lambda m, a: m["validations"]["sapien"]["flags"].update(held=1),
        "validations.sapien.flags: must map names to true/false",
    ),
    "contact_header": (
        lambda m, a: _drop(a, "contact_positions", "contact_normals"),
        "contacts: the JSON header and the contact arrays must be stored together",
    ),
    "contact_object": (
        lambda m, a: m["contacts"].update(object_id="other"),
        "contacts.object_id 'other' differs from the record's",
    ),
    "no_contacts": (
        lambda m, a: (m.update(contacts=None), _drop(a, "contact_positions", "contact_normals")),
        "steps.contacts: ok but no contacts stored",
    ),
    "no_grasp": (
        lambda m, a: (_drop(a, "wrist_pose", "q"), m.update(grasp_stage="")),
        "steps.retargeting: ok but no grasp (wrist_pose, q) stored",
    ),
    "grasp_stage": (
        lambda m, a: m.update(grasp_stage="magic"),
        "grasp_stage: 'magic' must be one of ['retargeting', 'refinement']",
    ),
    "stage_without_grasp": (
        lambda m, a: _drop(a, "wrist_pose", "q"),
        "grasp_stage: 'refinement' but no grasp is stored (expected '')",
    ),
    "stage_not_run": (
        lambda m, a: _steps(m, refinement={"ok": False, "reason": "not_run"}),
        "grasp_stage: 'refinement' but the refinement step did not run",
    ),
    "no_pregrasp": (
        lambda m, a: _drop(a, "pregrasp_wrist_pose", "pregrasp_q"),
        "steps.validation: attempted but the grasp or the pre-grasp is missing",
    ),
    "trials": (
        lambda m, a: m["validations"]["sapien"].update(trials=[{"name": "limits"}]),
        "validations.sapien.trials: must be a list of {name, reason, success}",
    ),
    "robustness": (
        lambda m, a: m["validations"]["sapien"].update(robustness=0.2),
        "validations.sapien.robustness: must be the share of trials held (1), got 0.2",
    ),
    "robustness_without_trials": (
        lambda m, a: m["validations"]["sapien"].update(trials=[], robustness=1.0),
        "validations.sapien.robustness: 1.0 but no trial is stored (null)",
    ),
    "robust_ok_but_a_trial_failed": (
        lambda m, a: (
            [v["trials"][1].update(success=False, reason="dropped") for v in m["validations"].values()]
            and [v.update(robustness=0.5) for v in m["validations"].values()]
        ),
        "steps.robust: ok, but the primary simulator's trials ['mass_x2'] failed",
    ),
    "robust_without_trials": (
        lambda m, a: [v.update(trials=[], robustness=None) for v in m["validations"].values()],
        "steps.robust: ran, but the primary simulator's verdict stores no trials",
    ),
    "robust_reason_not_a_trial": (
        lambda m, a: _steps(m, robust={"ok": False, "reason": "pose_9"}),
        "steps.robust: failed at 'pose_9', which is not a failed trial of the primary simulator",
    ),
    "attempt_robustness": (
        lambda m, a: m["attempts"][0].update(robustness=2),
        "attempts: must be a list of {refinement, robust, robustness, validation} verdicts",
    ),
    "format": (
        lambda m, a: m.update(version=4),
        "not a grasp record: format 'ges.grasp_record' version 4, expected 'ges.grasp_record' version 1 or 2 or 3",
    ),
    "contact_format": (
        lambda m, a: m["contacts"].update(format="x"),
        "cannot build the record (AssetError: not a contact set: format is 'x'",
    ),
}


def _rewrite(root: Path, file: str, mutate) -> None:
    meta, arrays = read_raw((root / file).read_bytes())
    mutate(meta, arrays)
    atomic_write_bytes(root / file, raw_to_bytes(meta, arrays))


@pytest.fixture
def dataset(tmp_path, records) -> Path:
    with DatasetWriter(tmp_path / "ds", CONFIG) as writer:
        for r in records:
            writer.add(r)
    assert validate_dataset(tmp_path / "ds") == []
    return tmp_path / "ds"


@pytest.mark.parametrize("case", sorted(CORRUPTIONS))
def test_validate_reports_each_damage(dataset, case):
    mutate, expected = CORRUPTIONS[case]
    file = record_relpath("procedural/box/000", "shadow")
    _rewrite(dataset, file, mutate)
    problems = validate_dataset(dataset)
    assert any(p.startswith(f"{file}: {expected}") for p in problems), problems


def test_record_problems_of_non_object_scalars():
    assert record_problems([1], {}) == ["record scalars are a list, not a JSON object"]


def test_validate_reports_file_level_damage(dataset):
    box, mug = record_relpath("procedural/box/000", "shadow"), record_relpath("procedural/mug/001", "shadow")
    data = (dataset / box).read_bytes()
    (dataset / box).write_bytes(data[: len(data) // 2])
    (dataset / mug).write_bytes(data)  # the box record under the mug's name
    problems = validate_dataset(dataset)
    assert problems[0].startswith(f"{box}: unreadable record (")
    assert f"{mug}: holds object 'procedural/box/000' with hand 'shadow', which belongs at {box}" in problems
    assert any(p.startswith(f"{mug}: manifest.json index disagrees with the record on [") for p in problems)


def test_validate_names_a_file_that_is_not_an_npz_archive(dataset):
    file = record_relpath("procedural/box/000", "shadow")
    (dataset / file).write_bytes(b"this is a text file, not a record\n")
    problems = validate_dataset(dataset)
    assert f"{file}: unreadable record (ValueError: not an .npz archive" in problems[0]
    assert "pickled" not in problems[0]


def test_validate_reports_non_object_json(dataset):
    file = record_relpath("procedural/box/000", "shadow")
    meta, arrays = read_raw((dataset / file).read_bytes())
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays, record_json=np.array("[1]"))
    (dataset / file).write_bytes(buf.getvalue())
    assert validate_dataset(dataset) == [
        f"{file}: unreadable record (ValueError: record_json holds a list, not an object)"
    ]


def test_validate_reports_manifest_damage(dataset):
    path = dataset / "manifest.json"
    manifest = json.loads(path.read_text())
    manifest["records"][0]["success"] = not manifest["records"][0]["success"]
    manifest["records"].append(dict(manifest["records"][1]))
    manifest["records"].append({"file": "records/x.npz"})
    del manifest["created"]
    path.write_text(json.dumps(manifest))
    problems = validate_dataset(dataset)
    first = manifest["records"][0]["file"]
    assert "manifest.json: missing key 'created'" in problems
    assert "manifest.json: records[4] repeats object 'procedural/duck/000' with hand 'allegro' or its file" in [
        p.replace("pybullet/duck", "procedural/duck") for p in problems
    ]
    assert any(p.startswith("manifest.json: records[5] lacks ['object_id'") for p in problems)
    assert f"{first}: manifest.json index disagrees with the record on ['success']" in problems
    path.write_text(json.dumps(dict(manifest, records={}, run_config=[])))
    problems = validate_dataset(dataset)
    assert "manifest.json: run_config must be an object" in problems
    assert "manifest.json: records must be a list" in problems


# --- command line -------------------------------------------------------------------------------


def test_cli_validate(dataset, capsys):
    code, out, _ = run_cli(capsys, "dataset", "validate", str(dataset))
    assert code == 0 and out.strip() == f"{dataset}: 4 records, no problems"
    _rewrite(dataset, record_relpath("procedural/box/000", "shadow"), CORRUPTIONS["normal"][0])
    _rewrite(dataset, record_relpath("procedural/mug/001", "shadow"), CORRUPTIONS["nan"][0])
    code, out, _ = run_cli(capsys, "dataset", "validate", str(dataset))
    lines = out.strip().splitlines()
    assert code == 1 and len(lines) == 3 and lines[-1] == f"2 problem(s) in {dataset}"
    code, out, _ = run_cli(capsys, "dataset", "validate", str(dataset.parent))
    assert code == 1 and "is not a grasp dataset: it has no manifest.json" in out


def test_cli_info_counts_rates_and_times(dataset, records, capsys):
    code, out, _ = run_cli(capsys, "dataset", "info", str(dataset))
    assert code == 0
    assert "4 records" in out.splitlines()[0]
    assert "by hand:      allegro 2, shadow 2" in out and "by category:  box 1, can 1, duck 1, mug 1" in out
    for hand in ("shadow", "allegro"):
        row = next(line for line in out.splitlines() if line.strip().startswith(f"{hand} / sapien"))
        mine = [r for r in records if r.hand == hand]
        for step in STEPS:  # expected cells computed from the records, not from the index
            tried = [r.steps[step] for r in mine if r.steps[step].attempted]
            ok = sum(s.ok for s in tried)
            median = np.median([s.seconds for s in tried])
            assert f"{ok}/{len(tried)} {100 * ok / len(tried):5.1f}% {median:.3f} s" in row, (step, row)
        assert f"{sum(r.success for r in mine)}/{len(mine)}" in row
    assert any(line.strip().startswith("all") for line in out.splitlines())


def test_cli_info_on_a_non_dataset_is_one_error_line(tmp_path, capsys):
    code, out, err = run_cli(capsys, "dataset", "info", str(tmp_path))
    assert code == 1 and out == "" and err.count("\n") == 1 and "is not a grasp dataset" in err


# --- version 1 (records with a free-form extra) ---------------------------------------------------


def _v1_files() -> list[Path]:
    return sorted(DATASET_V1.glob("records/*/*.npz"))


def test_version_1_dataset_opens_validates_and_reports(capsys):
    assert len(_v1_files()) == 4 and json.loads((DATASET_V1 / "manifest.json").read_text())["version"] == 1
    assert validate_dataset(DATASET_V1) == []
    records = {r.key: r for r in open_dataset(DATASET_V1)}
    assert len(records) == 4
    code, out, _ = run_cli(capsys, "dataset", "info", str(DATASET_V1))
    assert code == 0 and "4 records" in out.splitlines()[0]
    code, out, _ = run_cli(capsys, "dataset", "validate", str(DATASET_V1))
    assert code == 0 and "no problems" in out


@pytest.mark.parametrize("path", _v1_files(), ids=lambda p: p.stem)
def test_version_1_extra_becomes_the_typed_fields(path):
    """Every key of a version-1 extra lands in its field, and nothing is left in extra."""
    meta, arrays = read_raw(path.read_bytes())
    extra = meta["extra"]
    assert meta["version"] == 1 and extra
    record = record_from_raw(meta, arrays)
    assert record.extra == {}
    assert record.symmetric == extra.get("symmetric") and record.attempt == extra.get("attempt")
    assert record.attempts == tuple(AttemptVerdict(**a) for a in extra.get("attempts", ()))
    assert record.errors == extra.get("errors", {}) and record.picture == extra.get("picture")
    assert record.setup_seconds == extra.get("setup_seconds", {})
    assert record.validations == {sim: SimVerdict(**v) for sim, v in extra.get("validations", {}).items()}
    if "frozen" in extra:
        assert record.refinement == RefinementInfo(**{k: extra[k] for k in RefinementInfo.__dataclass_fields__})
    else:
        assert record.refinement is None
    assert record.validation_flags == (record.validations[record.simulator].flags if record.validations else {})


@pytest.mark.parametrize("path", _v1_files(), ids=lambda p: p.stem)
def test_version_1_record_written_again_is_the_current_version_and_reads_the_same(path):
    record = load_record(DATASET_V1, path.relative_to(DATASET_V1).as_posix())
    meta, arrays = record_to_raw(record)
    assert meta["version"] == RECORD_VERSION == 3 and record_problems(meta, arrays) == []
    assert record.total_seconds > 0  # a version-1 record holds its own times
    again = record_from_bytes(raw_to_bytes(meta, arrays))
    assert_same(again, record, times=False)
    assert again.total_seconds is None and all(v.seconds is None for v in again.validations.values())


def test_version_1_unknown_extra_keys_stay_in_extra():
    meta = {"version": 1, "extra": {"frozen": ["thumb"], "operator": "me", "errors": {"contacts": "x"}}}
    new = upgraded(meta)
    assert new["version"] == 2 and new["extra"] == {"operator": "me"} and new["errors"] == {"contacts": "x"}
    assert new["refinement"] == {"frozen": ["thumb"]}  # incomplete: the checks say so
    assert new["attempts"] == [] and new["validations"] == {} and new["picture"] is None
    assert upgraded({"version": 2, "extra": {"frozen": 1}})["extra"] == {"frozen": 1}  # only version 1 moves
    problems = record_problems(dict(record_to_raw(make_record("procedural/box/0"))[0], **meta), {})
    assert any(p.startswith("refinement: must be null or {frozen,") for p in problems), problems


def test_version_1_dataset_resumed_by_the_writer_becomes_version_2(tmp_path, records):
    import shutil

    root = tmp_path / "v1"
    shutil.copytree(DATASET_V1, root)
    run_config = json.loads((root / "manifest.json").read_text())["run_config"]
    with DatasetWriter(root, run_config) as writer:
        assert len(writer) == 4
        writer.add(records[0])
    assert json.loads((root / "manifest.json").read_text())["version"] == DATASET_VERSION == 2
    assert validate_dataset(root) == [] and len(open_dataset(root)) == 5

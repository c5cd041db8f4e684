"""The outside simulator package ``examples/ges-mujoco-sim``, installed as a user would, through ``ges``:

1. the SimBackend contract (``tests/test_sim_contract.py``, which adds every registered outside backend that
   declares ``contract_tolerances``) on ``mujoco``;
2. ``ges list sim`` names it with its distribution, and ``ges sim check --sim mujoco`` closes the Shadow hand
   on the box and lifts it;
3. Stage 1 with MuJoCo refining and validating (``ges synth --sim mujoco``) on one demo object, then the Stage 2
   scripted baseline (``ges env baseline --sim mujoco``) on that record;
4. a blow-up (what ``tests/test_sim_env_ids.py`` checks of the built-ins): a NaN in one env of three is reported
   for that env only, the others stay bit-identical to an undisturbed backend given the same commands, and the
   reset env then evolves bit-identically too, without MuJoCo printing or writing its log file.

Install: when the environment already holds ``ges-mujoco-sim`` (``pip install -e examples/ges-mujoco-sim``) the
commands use it; otherwise the package is built as a real wheel (``pip wheel --no-deps --no-build-isolation``)
and installed with ``pip install --no-deps --target`` into a temporary folder that the commands see through
``PYTHONPATH`` (the environment is left untouched; ``mujoco`` itself must be installed, as the package
declares). Either way the simulator comes in through its ``ges.plugins`` entry point. About 45-60 s on two
loaded cores, most of it the contract (23 checks) and the Stage 1 run.
"""

from __future__ import annotations

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers_packages import example_site, interpreter

from conftest import REPO

pytestmark = pytest.mark.sim

OBJECT = "procedural/box/000"
"""A demo object Allegro grasps and lifts in all three engines (Table 1 run)."""

if importlib.util.find_spec("mujoco") is None:  # the package's declared dependency
    pytest.skip("mujoco is not installed: pip install mujoco (ges-mujoco-sim's dependency)", allow_module_level=True)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path | None:
    """Folder holding the installed wheel, or None when the environment already has the package."""
    return example_site("ges-mujoco-sim", "ges-mujoco-sim", tmp_path_factory.mktemp("mujoco_pkg"))


@pytest.fixture(scope="module")
def run(site: Path | None):
    """``run(*argv)``: ``python ARGV`` in a fresh interpreter that sees the package; the finished process."""
    return interpreter(site)


def test_contract_runs_on_the_plugin(run) -> None:
    done = run("-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_sim_contract.py", "-k", "mujoco")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    passed = re.search(r"(\d+) passed", done.stdout)
    assert passed and int(passed.group(1)) >= 20, done.stdout[-2000:]  # every contract check, not a stray one
    assert "skipped" not in done.stdout.splitlines()[-1], done.stdout[-500:]


def test_listed_and_sim_check(run) -> None:
    listed = run("-m", "ges_core.cli", "list", "sim")
    assert listed.returncode == 0, listed.stderr
    line = next(ln for ln in listed.stdout.splitlines() if ln.strip().startswith("mujoco"))
    assert "ges-mujoco-sim 0.1.0" in line, line

    check = run("-m", "ges_core.cli", "sim", "check", "--sim", "mujoco", "--hand", "shadow")
    assert check.returncode == 0, check.stdout + check.stderr
    assert "hand shadow in mujoco" in check.stdout and ": OK" in check.stdout, check.stdout
    rose = float(re.search(r"box rose ([-\d.]+) mm", check.stdout).group(1))
    assert rose > 25.0, check.stdout  # of the 50 mm the wrist rose: the box went up with the hand


def test_stage1_validation_and_baseline(run, tmp_path: Path) -> None:
    out = tmp_path / "ds"
    synth = run("-m", "ges_core.cli", "synth", "--hands", "allegro", "--objects", OBJECT, "--sim", "mujoco",
                "--out", str(out), "-o", "robust.enabled=false", "--no-progress")  # fmt: skip
    assert synth.returncode == 0, synth.stdout + synth.stderr
    (path,) = sorted((out / "records" / "allegro").glob("*.npz"))
    with np.load(path, allow_pickle=False) as z:
        record = json.loads(str(z["record_json"]))
    assert record["simulator"] == "mujoco", record["simulator"]
    assert set(record["validations"]) == {"mujoco"}, record["validations"]
    verdict = record["validations"]["mujoco"]
    assert verdict["success"], verdict  # lifted 0.2 m and held by the fingertips, in MuJoCo
    assert verdict["flags"]["reached_grasp"] and verdict["flags"]["fingertips_touching"], verdict

    base = run("-m", "ges_core.cli", "env", "baseline", str(out), "--hand", "allegro", "--sim", "mujoco",
               "--out", str(tmp_path / "eval"), "--no-progress")  # fmt: skip
    assert base.returncode == 0, base.stdout + base.stderr
    assert "sim mujoco" in base.stdout, base.stdout
    (results,) = (tmp_path / "eval").glob("baseline-allegro-mujoco*.json")
    assert OBJECT in results.read_text(), results.read_text()[:500]


BLOWUP = """
import sys
import numpy as np
sys.path.insert(0, "tests")
from helpers_sim import allegro_test_hand, box_asset, open_q, UP
from ges_core.errors import SimulationError
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig

hand, registry = allegro_test_hand(), load_registry()

def scene():
    sim = registry.build_sim("mujoco", SceneConfig(num_envs=3))
    sim.load_hand(hand)
    sim.load_object(box_asset())
    sim.set_hand_state(open_q(hand, 3), np.tile(UP, (3, 1)))
    sim.set_joint_targets(np.tile(hand.description.closed_pose(0.5), (3, 1)))
    sim.step(5)
    return sim

def state(sim):
    return [*sim.joint_state(), sim.object_pose(), sim.contact_forces(list(hand.description.tip_links), "any")]

calm, hit = scene(), scene()
hit._data[1].qvel[hit._scenes[1].object_dof] = np.nan  # the object of env 1 only (engine internals: a test)
for sim in (calm, hit):
    try:
        sim.step(3)
        print("stepped", sim is hit)
    except SimulationError as exc:
        print("blown", list(exc.env_ids), str(exc).split(";")[0])
print("others", all(np.array_equal(a[[0, 2]], b[[0, 2]]) for a, b in zip(state(calm), state(hit))))
for sim in (calm, hit):
    sim.reset(env_ids=[1])
    sim.step(20)
print("restored", all(np.array_equal(a, b) for a, b in zip(state(calm), state(hit))))
"""


def test_a_blown_env_is_reported_alone_and_restored(run) -> None:
    done = run("-c", BLOWUP)
    assert done.returncode == 0, done.stdout + done.stderr
    lines = done.stdout.splitlines()
    assert "stepped False" in lines, done.stdout  # the undisturbed backend stepped without error
    blown = next(ln for ln in lines if ln.startswith("blown"))
    assert blown.startswith("blown [1] mujoco env 1: "), blown
    assert "others True" in lines and "restored True" in lines, done.stdout
    assert "WARNING" not in done.stdout + done.stderr, done.stdout + done.stderr  # MuJoCo's own print
    assert not (REPO / "MUJOCO_LOG.TXT").exists()


ARMATURE = """
import numpy as np
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_plugins.hands.shadow.assets import compile_model

registry = load_registry()
hand = registry.build_hand("shadow")
sim = registry.build_sim("mujoco", SceneConfig())
sim.load_hand(hand)
scene = sim._scenes[0]  # engine internals: a test
ours = scene.model.dof_armature[scene.hand_dof]
source = compile_model()  # the MJCF the Shadow is converted from, compiled by MuJoCo itself
theirs = [source.dof_armature[source.joint("robot0:" + n).dofadr[0]] for n in hand.description.joint_names]
print("same", bool(np.array_equal(ours, theirs)), sorted(set(ours.tolist())))
print("wrist", scene.model.dof_armature[scene.wrist_dof].tolist())
"""


def test_the_shadow_in_mujoco_has_its_mjcfs_armature(run) -> None:
    """The scene the plugin builds from the converted URDF gives each hand joint the armature MuJoCo compiles from
    the Shadow's own MJCF (docs/hands/shadow.md, "Armature"); the floating wrist's virtual joints get none."""
    done = run("-c", ARMATURE)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "same True [0.001, 0.005]" in done.stdout, done.stdout
    assert "wrist [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]" in done.stdout, done.stdout

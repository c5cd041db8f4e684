"""Loading a hand into a fresh backend, with its files made and parsed every time and once per process.

Every backend loads the hand again (Stage 1 builds one per trial). The plugins now make the engine-ready URDF file
once per process (``ges_core.hand_prep.engine_files.engine_file_memo``: SAPIEN's ``loading._prepared_urdf`` and
``pair_exclusion_bits``, PyBullet's ``hand_urdf.pybullet_hand_urdf``), and SAPIEN parses it once per process
(``loading._HAND_BUILDERS``). This measures, in one process with one torch thread, CPU seconds
(``time.process_time``):

* **per backend**: build a backend, load the hand, close it, for each hand and engine, both ways (median of
  ``--repeats`` rounds, alternating);
* **the pipeline**: Stage 1 (``run_synthesis``, the defaults: robust trials on) over object 000 of ``--procedural``
  categories with both hands, validated in SAPIEN and PyBullet, both ways, comparing every record (verdicts,
  placement histories, joints and wrist pose) and the whole run's CPU seconds and the records' ``setup_seconds``.

    python benchmarks/hand_load_memo.py [--procedural N] [--repeats N] [--results NAME]

Prints markdown tables and writes ``benchmarks/results/NAME.json`` (default NAME ``hand_load_memo``).
"""

from __future__ import annotations

import argparse
import contextlib
import statistics
import tempfile
import time
from pathlib import Path

from stage1_speed import run_pipeline
from validation_reads import outcome

from ges_core.dataset import software_versions
from ges_core.objects.library import LibraryConfig
from ges_core.objects.procedural import CATEGORIES
from ges_core.registry import load_registry
from ges_core.sim import SceneConfig
from ges_core.synthesis import SynthesisConfig
from ges_core.threads import set_torch_threads
from ges_plugins.sims.pybullet import hand_urdf, scene
from ges_plugins.sims.sapien import loading

from _results import code_state, results_path, write_results

HANDS = ("allegro", "shadow")
SIMS = ("sapien", "pybullet")


class _Forgetful(dict):
    """A builder cache that keeps nothing: SAPIEN parses the URDF at every hand load, as before."""

    def __setitem__(self, key, value) -> None:
        pass


@contextlib.contextmanager
def unmemoized():
    """The plugins without their memos: the file is made and parsed at every hand load, as before."""
    saved = (loading._prepared_urdf, loading._pair_exclusion_bits, loading._HAND_BUILDERS, hand_urdf.pybullet_hand_urdf)
    loading._prepared_urdf = loading._prepared_urdf.__wrapped__
    loading._pair_exclusion_bits = loading._pair_exclusion_bits.__wrapped__
    loading._HAND_BUILDERS = _Forgetful()
    hand_urdf.pybullet_hand_urdf = scene.pybullet_hand_urdf = hand_urdf.pybullet_hand_urdf.__wrapped__
    try:
        yield
    finally:
        loading._prepared_urdf, loading._pair_exclusion_bits, loading._HAND_BUILDERS, memo = saved
        hand_urdf.pybullet_hand_urdf = scene.pybullet_hand_urdf = memo


def load(registry, hand, sim_name: str) -> float:
    """CPU seconds to build a backend, load ``hand`` and close it."""
    start = time.process_time()
    with registry.build_sim(sim_name, SceneConfig()) as sim:
        sim.load_hand(hand)
    return time.process_time() - start


def per_backend(repeats: int) -> dict:
    """{hand/sim: {"every_time": ms, "once": ms}}: medians over ``repeats`` alternating rounds of one backend."""
    registry = load_registry(autoload=False)
    out = {}
    for hand_name in HANDS:
        hand = registry.build_hand(hand_name)
        for sim_name in SIMS:
            samples = {"every_time": [], "once": []}

            load(registry, hand, sim_name)  # imports and the cached files
            for _ in range(repeats):
                with unmemoized():
                    samples["every_time"].append(load(registry, hand, sim_name))
                samples["once"].append(load(registry, hand, sim_name))
            out[f"{hand_name}/{sim_name}"] = {k: 1e3 * statistics.median(v) for k, v in samples.items()}
    return out


def pipeline(ids: list[str], folder: Path) -> dict:
    """Both ways over ``ids`` with both hands, SAPIEN and PyBullet validating; records compared."""
    library = LibraryConfig(sources=("procedural",), decompose=True)
    config = SynthesisConfig(library=library, validate_sims=("sapien", "pybullet"))
    run_pipeline(ids[:1], ["allegro"], config, folder / "warm", "cpu")
    runs, cpu = {}, {}
    for variant in ("every_time", "once"):
        with unmemoized() if variant == "every_time" else contextlib.nullcontext():
            records, spent = run_pipeline(ids, list(HANDS), config, folder / variant, "cpu")
        runs[variant], cpu[variant] = {r.key: r for r in records}, spent["cpu"]
        print(f"pipeline {variant}: {len(records)} records, {spent['cpu']:.1f} CPU s")
    keys = sorted(runs["once"])
    setup = {v: [sum(runs[v][k].setup_seconds.values()) for k in keys] for v in runs}
    return {
        "records": len(keys),
        "identical": sum(outcome(runs["every_time"][k]) == outcome(runs["once"][k]) for k in keys),
        "cpu_seconds": cpu,
        "setup_seconds_median": {v: statistics.median(s) for v, s in setup.items()},
        "setup_seconds_sum": {v: sum(s) for v, s in setup.items()},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--procedural", type=int, default=12, help="object 000 of the first N categories")
    parser.add_argument("--repeats", type=int, default=15, help="rounds of the per-backend timing")
    parser.add_argument("--results", default="hand_load_memo", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the timings
    set_torch_threads(1)
    backends = per_backend(args.repeats)
    print("\n| hand / engine | backend + hand load, ms: made and parsed every time / once per process | ratio |")
    print("|---|---|---|")
    for key, row in backends.items():
        print(f"| {key} | {row['every_time']:.1f} / {row['once']:.1f} | {row['once'] / row['every_time']:.2f} |")
    ids = [f"procedural/{c}/000" for c in list(CATEGORIES)[: args.procedural]]
    with tempfile.TemporaryDirectory() as tmp:
        run = pipeline(ids, Path(tmp))
    cpu, setup = run["cpu_seconds"], run["setup_seconds_sum"]
    print(
        f"\npipeline ({len(ids)} objects x 2 hands, SAPIEN + PyBullet): {run['identical']} of {run['records']} "
        f"records identical; whole run {cpu['every_time']:.1f} / {cpu['once']:.1f} CPU s "
        f"(ratio {cpu['once'] / cpu['every_time']:.2f}); setup seconds summed over records "
        f"{setup['every_time']:.1f} / {setup['once']:.1f}"
    )
    write_results(results, {
        "benchmark": "hand_load_memo", "per_backend_ms": backends, "pipeline": run, "objects": ids,
        "clock": "time.process_time (one process, one torch thread)", "software": software_versions(),
        "code": code_state(),
    })  # fmt: skip


if __name__ == "__main__":
    main()

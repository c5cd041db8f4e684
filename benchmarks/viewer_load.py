"""Grasp viewer load time: ``ges view`` on a 40-record dataset until headless Chromium shows the scene.

Per repeat, with a headless Chromium already open on about:blank (``ges_core.viewer.chromium.HeadlessPage``):

* start ``ges view DATASET --port P`` as a user does (a fresh process: imports, dataset open, first hand and object
  loaded, first scene built) and wait for the line with its URL: **server ready**;
  the command's own "ready in" (dataset open, first hand and object, first scene; the rest is Python and imports);
* navigate the tab to the URL and take screenshots until the 3D canvas shows the object and the hand
  (``canvas_pixels``: > 300 object-orange and > 3000 hand-blue pixels): **page shown**. The page was drawn between
  the previous screenshot and that one; both times are kept (a screenshot takes 0.1-25 s on a loaded machine:
  SwiftShader draws WebGL on the CPU);
* total = server start to page shown.

Then, in this process, the server-side cost of switching records: ``GraspViewer.show`` for every record of the
dataset in turn (read the record, build its scene, send what changed), and the hand toggle on each object.

The dataset: ``--dataset`` (default runs/demo/dataset, what ``ges demo`` writes: 20 objects x 2 hands); when it is
missing, ``--make`` runs ``ges demo`` to write it (about 3-10 minutes on 2 cores).
Prints a table, writes benchmarks/results/NAME.json (default NAME viewer_load).
Usage: python benchmarks/viewer_load.py [--dataset DIR] [--make] [--repeats 3] [--size 960 600] [--results NAME]
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

from ges_core.viewer.chromium import HeadlessPage, canvas_pixels

from _results import code_state, results_path, write_results

REPO = Path(__file__).resolve().parent.parent
SHOWN = {"object": 300, "hand": 3000}
"""Pixels of the object's and the hand's colours that mean 'the scene is drawn' (the test's thresholds)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def one_load(dataset: Path, size: tuple[int, int], timeout: float) -> dict:
    """Seconds from starting ``ges view`` to its URL line, and to the first screenshot showing the scene."""
    port = free_port()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    with HeadlessPage(size=size) as page:
        page.screenshot()  # the browser is up and drawing before the clock starts
        t0 = time.perf_counter()
        cmd = [sys.executable, "-m", "ges_core.cli", "view", str(dataset), "--port", str(port)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env, cwd=REPO)
        try:
            line = ""
            while "ges view:" not in line:
                line = proc.stdout.readline()
                if not line and proc.poll() is not None:
                    raise RuntimeError(f"ges view exited with {proc.returncode} before serving")
            ready = time.perf_counter() - t0
            page.navigate(f"http://127.0.0.1:{port}")
            shots, before, counts = 0, ready, {}
            while time.perf_counter() - t0 < timeout:
                counts = canvas_pixels(page.screenshot())
                shots += 1
                now = time.perf_counter() - t0
                if all(counts[k] > v for k, v in SHOWN.items()):
                    return {
                        "server_ready_s": ready,
                        "viewer_ready_s": float(line.split("ready in ")[1].split(" s")[0]),
                        "shown_after_s": before,
                        "shown_by_s": now,
                        "screenshots": shots,
                        "pixels": counts,
                        "records": int(line.split(" records")[0].split()[-1]),
                    }
                before = now
            raise RuntimeError(f"the scene did not show within {timeout:.0f} s (last pixel counts {counts})")
        finally:
            proc.terminate()
            proc.wait(timeout=30)


def switch_times(dataset: Path) -> dict:
    """Server-side seconds of ``show`` per record (every record in turn) and of the hand toggle per object."""
    from ges_core.viewer import start

    viewer = start(dataset, port=free_port())
    try:
        keys = [(e["object_id"], e["hand"]) for e in viewer.data.dataset.entries]
        show = []
        for object_id, hand in keys:
            t = time.perf_counter()
            viewer.show(object_id, hand)
            show.append(time.perf_counter() - t)
        toggle = []
        for object_id in viewer.data.objects():
            viewer.show(object_id, viewer.data.hands(object_id)[0])
            t = time.perf_counter()
            viewer.other_hand()
            toggle.append(time.perf_counter() - t)
    finally:
        viewer.server.stop()
    return {
        "show_median_s": statistics.median(show),
        "show_max_s": max(show),
        "toggle_median_s": statistics.median(toggle),
        "records": len(keys),
    }


def make_dataset(dataset: Path) -> None:
    out = dataset.parent
    print(f"writing the demo dataset to {out} (ges demo; several minutes)", flush=True)
    cmd = [sys.executable, "-m", "ges_core.cli", "demo", "--out", str(out), "--no-progress"]
    subprocess.run(cmd, check=True, cwd=REPO, env={**os.environ, "OMP_NUM_THREADS": "1"})


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dataset", type=Path, default=REPO / "runs" / "demo" / "dataset")
    parser.add_argument("--make", action="store_true", help="run ges demo to write the dataset when it is missing")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, nargs=2, default=(960, 600), metavar=("W", "H"))
    parser.add_argument("--timeout", type=float, default=180.0, help="seconds to wait for the scene per repeat")
    parser.add_argument("--results", default="viewer_load", help="benchmarks/results/NAME.json")
    args = parser.parse_args()
    results = results_path(args.results)  # a bad name stops here, not after the loads
    load_before = os.getloadavg()[0]  # the machine is shared: the figures scale with its load
    if not (args.dataset / "manifest.json").is_file():
        if not args.make:
            sys.exit(f"no dataset at {args.dataset}: run 'ges demo' first, or pass --make")
        make_dataset(args.dataset)
    loads = [one_load(args.dataset, tuple(args.size), args.timeout) for _ in range(args.repeats)]
    switches = switch_times(args.dataset)
    median = {
        k: statistics.median(r[k] for r in loads)
        for k in ("server_ready_s", "viewer_ready_s", "shown_after_s", "shown_by_s")
    }
    print_table(loads, median, switches)
    write_results(
        results,
        {
            "what": "ges view: server start to URL, and to the first headless-Chromium screenshot showing the scene",
            "dataset": str(args.dataset.relative_to(REPO) if args.dataset.is_relative_to(REPO) else args.dataset),
            "window": list(args.size),
            "loads": loads,
            "median": median,
            "switch": switches,
            "load_average_1min": {"before": load_before, "after": os.getloadavg()[0]},
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
            "code": code_state(),
        },
    )


def print_table(loads: list[dict], median: dict, switches: dict) -> None:
    print(f"\nges view on {loads[0]['records']} records; canvas pixels when shown (last repeat): {loads[-1]['pixels']}")
    print(f"{'repeat':>7} {'server ready':>13} {'of which viewer':>16} {'shown between':>16} {'screenshots':>12}")
    for i, r in enumerate(loads, 1):
        shown = f"{r['shown_after_s']:.1f}-{r['shown_by_s']:.1f} s"
        print(
            f"{i:>7} {r['server_ready_s']:>11.1f} s {r['viewer_ready_s']:>14.1f} s {shown:>16} {r['screenshots']:>12}"
        )
    shown = f"{median['shown_after_s']:.1f}-{median['shown_by_s']:.1f} s"
    print(f"{'median':>7} {median['server_ready_s']:>11.1f} s {median['viewer_ready_s']:>14.1f} s {shown:>16}")
    print(
        f"switching records (server side, {switches['records']} records): show median "
        f"{1000 * switches['show_median_s']:.0f} ms, max {1000 * switches['show_max_s']:.0f} ms; "
        f"other-hand toggle median {1000 * switches['toggle_median_s']:.0f} ms"
    )


if __name__ == "__main__":
    main()

"""Every benchmark script that writes results takes ``--results NAME`` and resolves it with ``results_path``.

A static check of the scripts' source text (no benchmark is imported or run): a script under ``benchmarks/`` (not a
``_`` helper) that calls ``write_results(`` must also contain ``"--results"`` and ``results_path(``, so its output
name can be chosen and a bad name (a path, ``.json``) is refused before any work (``benchmarks/_results.py``).
"""

from __future__ import annotations

from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def offenders(folder: Path = BENCHMARKS) -> list[str]:
    """The scripts of ``folder`` that call ``write_results(`` without ``"--results"`` or ``results_path(``."""
    bad = []
    for script in sorted(folder.glob("*.py")):
        if script.name.startswith("_"):
            continue
        text = script.read_text(encoding="utf-8")
        if "write_results(" not in text:
            continue
        missing = [s for s in ('"--results"', "results_path(") if s not in text]
        if missing:
            bad.append(f"{script.name} (no {' and no '.join(missing)})")
    return bad


def test_every_results_writer_takes_results_name() -> None:
    bad = offenders()
    assert not bad, (
        "benchmark scripts that write results without a --results NAME flag resolved by results_path() "
        f"(see benchmarks/stage1_robust.py): {', '.join(bad)}"
    )


def test_the_check_finds_a_script_without_the_flag(tmp_path: Path) -> None:
    (tmp_path / "_helper.py").write_text("write_results(path, {})\n")  # helpers are not scripts
    (tmp_path / "quiet.py").write_text("print('writes nothing')\n")
    (tmp_path / "good.py").write_text(
        'parser.add_argument("--results", default="good")\nresults = results_path(args.results)\n'
        "write_results(results, {})\n"
    )
    (tmp_path / "no_flag.py").write_text('write_results(RESULTS / "no_flag.json", {})\n')
    (tmp_path / "no_check.py").write_text('parser.add_argument("--results")\nwrite_results(RESULTS, {})\n')
    assert offenders(tmp_path) == [
        "no_check.py (no results_path()",
        'no_flag.py (no "--results" and no results_path()',
    ]

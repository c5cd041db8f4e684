"""``ges demo``, ``ges synth`` and ``ges retarget``: run Stage 1 grasp synthesis from the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import positive_int
from ges_core.cli.cmd_objects import SOURCE_CHOICES, add_user_options, property_overrides, user_id, user_sources
from ges_core.config import parse_model
from ges_core.errors import ConfigError
from ges_core.executors import add_executor_options, executor_options


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges demo``, ``ges synth`` and ``ges retarget``."""
    dp = sub.add_parser("demo", help="synthesize and validate grasps of ~20 built-in objects with both hands")
    dp.add_argument("--config", type=Path, metavar="PATH", help="demo config (default configs/demo.yaml)")
    _common(dp)
    add_user_options(dp)
    dp.add_argument(
        "--objects", nargs="+", metavar="ID", help="object ids (default: the demo set, or all of --user-dir)"
    )
    dp.add_argument("--out", metavar="DIR", help="output folder (default runs/demo)")
    dp.add_argument(
        "--fresh", action="store_true", help="start over: move an existing output folder aside to DIR.old-N first"
    )
    dp.set_defaults(func=run_demo_cmd)

    sp = sub.add_parser("synth", help="generate a grasp dataset for chosen hands, objects and simulator")
    sp.add_argument("--config", type=Path, metavar="PATH", help="synthesis config YAML (SynthesisConfig)")
    _common(sp)
    sp.add_argument("--hands", nargs="+", default=["shadow", "allegro"], metavar="HAND", help="hands (default both)")
    add_user_options(sp)
    sp.add_argument("--objects", nargs="+", metavar="ID", help="object ids (default: the whole library)")
    sp.add_argument("--limit", type=positive_int, metavar="N", help="only the first N objects (N >= 1)")
    sp.add_argument("--sim", metavar="NAME", help="simulator of refinement and validation (sets both)")
    sp.add_argument("--pictures", type=Path, metavar="DIR", help="also draw a PNG per grasp and DIR/contact_sheet.png")
    sp.add_argument("--out", type=Path, required=True, metavar="DIR", help="dataset folder (created or resumed)")
    sp.add_argument(
        "--allow-config-change",
        action="store_true",
        help="resume a dataset written with other settings (stored records keep theirs; the old config is kept in "
        "the manifest's config_history)",
    )
    sp.set_defaults(func=run_synth_cmd)

    rp = sub.add_parser("retarget", help="retarget a dataset's stored contacts to another hand and validate")
    rp.add_argument("dataset", type=Path, metavar="DATASET", help="dataset folder holding records of --from")
    rp.add_argument("--from", dest="source_hand", required=True, metavar="HAND", help="hand whose contacts to reuse")
    rp.add_argument("--to", dest="target_hand", required=True, metavar="HAND", help="hand to produce grasps for")
    rp.add_argument("--out", type=Path, metavar="DIR", help="write the new records here (default: DATASET)")
    rp.add_argument("--workers", type=positive_int, default=1, metavar="N", help="worker processes (default 1)")
    add_executor_options(rp)
    rp.add_argument("--no-progress", action="store_true", help="no progress bar")
    rp.set_defaults(func=run_retarget_cmd)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", action="append", default=[], metavar="KEY=VALUE", dest="overrides", help="override a value")
    p.add_argument("--workers", type=positive_int, metavar="N", help="worker processes (N >= 1)")
    add_executor_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _move_aside(out: Path) -> None:
    """Rename an existing ``out`` to the first free ``out.old-N`` (nothing is deleted) and say so."""
    if not out.exists():
        return
    n = 1
    while out.with_name(f"{out.name}.old-{n}").exists():
        n += 1
    aside = out.rename(out.with_name(f"{out.name}.old-{n}"))
    print(f"--fresh: moved the earlier {out} to {aside}")


def _registry(args: argparse.Namespace):
    from ges_core.synthesis.run.tasks import RegistrySpec

    return RegistrySpec(args.registry, tuple(args.registry_overrides), tuple(args.no_plugin))


def run_demo_cmd(args: argparse.Namespace) -> int:
    """Run the demo and print its summary table."""
    from ges_core.synthesis.run.demo import default_demo_config, run_demo

    where = executor_options(args)
    overrides = list(args.overrides)
    overrides += [f"out={args.out}"] if args.out else []
    overrides += [f"workers={args.workers}"] if args.workers is not None else []
    config = default_demo_config(args.config, tuple(overrides))
    config = config.model_copy(update={"synthesis": with_user_library(config.synthesis, args)})
    if args.objects or args.user_dir:
        ids = [user_id(i, args) for i in args.objects] if args.objects else _all_ids(config.synthesis)
        config = config.model_copy(update={"objects": ids})
    _check_objects(config.synthesis, config.object_ids())
    if args.fresh:
        _move_aside(Path(config.out))
    _prepare(config.synthesis, config.object_ids(), config.hands, config.workers, args)
    print(run_demo(config, registry=_registry(args), progress=not args.no_progress, **where))
    return 0


def run_synth_cmd(args: argparse.Namespace) -> int:
    """Generate a dataset and print its table."""
    from ges_core.config import load_config
    from ges_core.synthesis import SynthesisConfig, run_synthesis

    where = executor_options(args)
    overrides = list(args.overrides)
    overrides += [f"refine_sim={args.sim}", f"validate_sims=[{args.sim}]"] if args.sim else []
    config = with_user_library(load_config(SynthesisConfig, args.config, overrides), args)
    ids = [user_id(i, args) for i in args.objects] if args.objects else _all_ids(config)
    ids = ids if args.limit is None else ids[: args.limit]
    _check_objects(config, ids)
    _prepare(config, ids, args.hands, args.workers or 1, args)
    report = run_synthesis(
        ids, args.hands, config, args.out, workers=args.workers or 1, progress=not args.no_progress,
        registry=_registry(args), pictures=args.pictures, allow_config_change=args.allow_config_change, **where,
    )  # fmt: skip
    if report.redone:
        print(
            f"{len(report.redone)} stored record(s) no longer fit their object as the library builds it now "
            f"(e.g. {report.redone[0][0]}, {report.redone[0][1]}): set aside in {args.out}/.damaged/ and made again"
        )
    records = _print_table(args.out, {(o, h) for o in ids for h in args.hands})
    if args.pictures is not None:
        from ges_core.synthesis.run.demo import draw_contact_sheet

        print(f"contact sheet: {draw_contact_sheet(records, args.pictures / 'contact_sheet.png')}")
    return 0


def with_user_library(config, args: argparse.Namespace):
    """``config`` (a SynthesisConfig) with ``--user-dir``, ``--with-library`` and the per-object options applied
    to its ``library`` section (that section is stored in the dataset, so Stage 2 rebuilds the same library)."""
    from ges_core.objects.library import LibraryConfig

    lib = config.library
    update: dict = {}
    if args.user_dir or args.with_library:
        update = {"user_dir": args.user_dir, "user_scale": args.user_scale, "sources": user_sources(args, lib.sources)}
    props = property_overrides(args)
    if props:
        merged = {oid: p.model_dump(exclude_none=True) for oid, p in lib.object_properties.items()}
        for oid, values in props.items():
            merged[oid] = {**merged.get(oid, {}), **values}
        update["object_properties"] = merged
    if not update:
        return config
    settings = {name: getattr(lib, name) for name in LibraryConfig.model_fields}
    library = parse_model(LibraryConfig, {**settings, **update}, where="object library options")
    return config.model_copy(update={"library": library})


def _all_ids(config) -> list[str]:
    return [o.object_id for o in config.library.build().list()]


def _prepare(config, ids: list[str], hands, workers: int, args: argparse.Namespace) -> None:
    """Decompose the hands' collision meshes whose hulls stand far off them (an unknown hand fails here, before any
    CoACD), then process the run's file meshes and decompose the concave ones missing a decomposition, with bars."""
    from ges_core.hand_prep.prepare import decompose_deep_hulls, format_decomposed
    from ges_core.objects.prepare import prepare_before_run

    registry = _registry(args).load()
    for name in hands:
        done = decompose_deep_hulls(registry.build_hand(name), progress=not args.no_progress)
        if line := format_decomposed(name, done):
            print(line)
    results = prepare_before_run(config.library.build(), ids, workers=workers, progress=not args.no_progress)
    done = [r for r in results if r.status == "decomposed"]
    if done:
        seconds = sum(r.seconds for r in done)
        print(f"decomposed {len(done)} concave objects with CoACD ({seconds:.1f} s; cached for later runs)")


def run_retarget_cmd(args: argparse.Namespace) -> int:
    """Retarget stored contacts of --from to --to; print a per-hand success table."""
    from ges_core.dataset import open_dataset
    from ges_core.synthesis import SynthesisConfig, run_synthesis

    where = executor_options(args)
    dataset = open_dataset(args.dataset)
    if args.source_hand == args.target_hand:
        raise ConfigError(f"ges retarget: --from and --to are both '{args.source_hand}'; name two different hands")
    ids = [e["object_id"] for e in dataset.entries if e["hand"] == args.source_hand]
    if not ids:
        hands = sorted({e["hand"] for e in dataset.entries})
        raise ConfigError(
            f"dataset {args.dataset} holds no record of hand '{args.source_hand}' "
            f"(it holds: {', '.join(hands) or 'none'})"
        )
    config = SynthesisConfig.of_dataset(dataset)
    out = args.out or args.dataset
    run_synthesis(
        ids, [args.target_hand], config, out, workers=args.workers, progress=not args.no_progress,
        registry=_registry(args), source=(str(args.dataset), args.source_hand), **where,
    )  # fmt: skip
    # the source hand's records from DATASET, the target hand's from where they were written (a dataset
    # holding both hands, like the demo's, would otherwise count its own target-hand records too)
    _print_table(args.dataset, {(o, args.source_hand) for o in ids}, extra=(out, {(o, args.target_hand) for o in ids}))
    return 0


def _check_objects(config, ids: list[str]) -> None:
    """UnknownObjectError (with close matches) for an id the configured library does not hold; a ConfigError
    naming the missing option for an id of a source the run does not use (``user/...`` without ``--user-dir``)."""
    sources = config.library.sources
    for oid in ids:
        source = oid.split("/", 1)[0]
        if source == "user" and "user" not in sources:
            raise ConfigError(
                f"object '{oid}' is a user object but no user folder is given: add --user-dir DIR "
                "(the folder holding <category>/<instance>.obj), or set library.user_dir in the config"
            )
        if source in SOURCE_CHOICES and source not in sources:
            raise ConfigError(
                f"object '{oid}' is of the '{source}' source, which this run's library does not use "
                f"(library.sources: {', '.join(sources)}); add it, e.g. "
                f"-o 'library.sources=[{', '.join(sources)}, {source}]'"
                + (" (or --with-library beside --user-dir)" if "user" in sources else "")
            )
    library = config.library.build()
    for oid in ids:
        library.entry(oid)


def _print_table(
    root: Path, wanted: set[tuple[str, str]], extra: tuple[Path, set[tuple[str, str]]] | None = None
) -> list:
    """The Table 1 summary of ``root``'s records in ``wanted`` (and of ``extra``: another folder and its keys)."""
    from ges_core.dataset import open_dataset
    from ges_core.synthesis.run.table import format_table, table_rows

    records = [r for r in open_dataset(root) if r.key in wanted]
    if extra is not None:
        records += [r for r in open_dataset(extra[0]) if r.key in extra[1]]
    print(format_table(table_rows(records)))
    return records

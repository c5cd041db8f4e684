"""``ges objects list`` and ``ges objects prepare``: the object library from the command line."""

from __future__ import annotations

import argparse
from pathlib import Path

from ges_core.cli.args import non_negative_int, positive_float, positive_int
from ges_core.errors import AssetError, ConfigError

SOURCE_CHOICES = ("procedural", "pybullet", "real", "user")
SPLIT_CHOICES = ("train", "unseen_object", "unseen_category")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ges objects {list,prepare}``."""
    p = sub.add_parser("objects", help="list objects and prepare their collision shapes")
    osub = p.add_subparsers(dest="objects_command", metavar="ACTION", required=True)
    lp = osub.add_parser("list", help="list objects with category, source and split")
    _library_options(lp)
    lp.add_argument("--split", choices=SPLIT_CHOICES, help="only this split")
    lp.add_argument("--objects", nargs="+", metavar="ID", help="only these object ids (user ids without user/ too)")
    lp.add_argument(
        "--sizes", action="store_true", help="also load each mesh: extents, min width (cm), mass and friction"
    )
    lp.set_defaults(func=run_list)
    pp = osub.add_parser("prepare", help="validate objects and cache convex decompositions (CoACD)")
    _library_options(pp)
    pp.add_argument("--workers", type=positive_int, default=1, metavar="N", help="parallel processes (default 1)")
    pp.add_argument("--limit", type=positive_int, metavar="N", help="only the first N objects")
    pp.add_argument(
        "--objects", "--ids", dest="ids", nargs="+", metavar="ID", help="only these object ids (--ids: the older name)"
    )
    pp.add_argument("--coacd", choices=("fast", "default"), default="fast", help="CoACD settings (default fast)")
    pp.add_argument("--no-progress", action="store_true", help="no progress bar")
    pp.set_defaults(func=run_prepare)


def add_user_options(p: argparse.ArgumentParser) -> None:
    """``--user-dir`` and the per-object property options (``ges objects``, ``ges synth``, ``ges demo``)."""
    p.add_argument(
        "--user-dir", type=Path, metavar="DIR", help="your objects, laid out DIR/<category>/<instance>.obj: "
        "then only they are used (ids user/<category>/<instance>) unless --with-library",
    )  # fmt: skip
    p.add_argument("--user-scale", type=positive_float, default=1.0, help="user files' unit in metres (0.001 for mm)")
    p.add_argument("--with-library", action="store_true", help="with --user-dir: also the built-in objects")
    for option, unit in (("mass", "kg"), ("density", "kg/m^3"), ("friction", "coefficient")):
        p.add_argument(
            f"--{option}", action="append", default=[], metavar="ID=VALUE",
            help=f"{option} ({unit}) of one object, over objects.yaml (repeatable)",
        )  # fmt: skip
    p.add_argument(
        "--rest", action="append", default=[], metavar="ID=MODE",
        help="how one object rests on the table, over objects.yaml (repeatable): stable (its most probable pose, the "
        "default), graspable (the most probable pose a hand can squeeze across: 12 cm or less) or "
        "as_authored (its file's +z up, e.g. a scan that stands); every object: -o library.rest=MODE",
    )  # fmt: skip


def user_sources(args: argparse.Namespace, default: tuple[str, ...]) -> tuple[str, ...]:
    """The sources a command uses: ``user`` alone with ``--user-dir`` (plus ``default`` with ``--with-library``)."""
    if getattr(args, "with_library", False) and not args.user_dir:
        raise ConfigError("--with-library adds the built-in objects to a user folder: give the folder with --user-dir")
    if not args.user_dir:
        return default
    return ("user",) + (tuple(s for s in default if s != "user") if args.with_library else ())


def property_overrides(args: argparse.Namespace) -> dict[str, dict]:
    """``{object id: {mass|density|friction|rest: value}}`` from ``--mass``, ``--density``, ``--friction`` and
    ``--rest``."""
    from ges_core.objects.properties import parse_assignments

    merged: dict[str, dict] = {}
    for field in ("mass", "density", "friction"):
        for oid, values in parse_assignments(getattr(args, field), field, option=f"--{field}").items():
            merged.setdefault(user_id(oid, args), {}).update(values)
    example = "real/box/cracker_box=as_authored"
    rests = parse_assignments(args.rest, "rest", option="--rest", convert=str.strip, example=example)
    for oid, values in rests.items():
        merged.setdefault(user_id(oid, args), {}).update(values)
    return merged


KNOWN_PREFIXES = ("procedural/", "pybullet/", "real/", "user/")


def user_id(oid: str, args: argparse.Namespace) -> str:
    """``oid``, with ``user/`` put in front when ``--user-dir`` is given and it names no source (``mug/blue``)."""
    return f"user/{oid}" if args.user_dir and not oid.startswith(KNOWN_PREFIXES) else oid


def _library_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", choices=SOURCE_CHOICES, action="append", help="only this source (repeatable)")
    add_user_options(p)
    p.add_argument("--count", type=non_negative_int, default=10, metavar="N", help="procedural objects per category")
    p.add_argument("--seed", type=non_negative_int, default=0, help="procedural seed")
    p.add_argument("--split-seed", type=non_negative_int, default=0, help="seed of the splits")
    p.add_argument(
        "--held-out",
        nargs="*",
        metavar="CATEGORY",
        help="categories always in the unseen-category split (default: stamp cross barrel channel; none: the "
        "seeded draw over every category)",
    )
    p.add_argument(
        "--normalize", type=positive_float, metavar="M", help="scale each object's largest extent to M metres"
    )
    p.add_argument(
        "--max-faces", type=positive_int, metavar="N", help="simplify meshes with more faces to N (default 200000)"
    )


def library_from_args(args: argparse.Namespace, **extra):
    """The :class:`ObjectLibrary` the command-line options describe."""
    from ges_core.config import parse_model
    from ges_core.objects.library import LibraryConfig, ObjectLibrary

    sources = tuple(args.source) if args.source else user_sources(args, ("procedural", "pybullet"))
    settings = {
        "object_properties": property_overrides(args),
        "sources": sources,
        "seed": args.seed,
        "procedural_count": args.count,
        "user_dir": args.user_dir,
        "user_scale": args.user_scale,
        "normalize_size": args.normalize,
        "split_seed": args.split_seed,
        **({"held_out_categories": tuple(args.held_out)} if args.held_out is not None else {}),
        **({"max_faces": args.max_faces} if args.max_faces is not None else {}),
        **extra,
    }
    return ObjectLibrary(parse_model(LibraryConfig, settings, where="object library options"))


def run_list(args: argparse.Namespace) -> int:
    """Print ``id  category  source  split`` per object (and sizes with ``--sizes``)."""
    library = library_from_args(args)
    rows = library.list(split=args.split)
    if args.objects:  # unknown ids: UnknownObjectError with close matches, before anything is printed
        wanted = {library.entry(user_id(i, args)).object_id for i in args.objects}
        rows = [r for r in rows if r.object_id in wanted]
    invalid = 0
    for info in rows:
        line = f"{info.object_id:<34} {info.category:<14} {info.source:<10} {info.split:<15}"
        problem = library.entry(info.object_id).problem
        if problem is not None:  # found while listing (two files give one id): no mesh to read
            invalid += 1
            line += f"  INVALID: {problem}"
        elif args.sizes:
            try:
                ext, width = library.extents(info.object_id) * 100, library.min_width(info.object_id) * 100
                line += f"  {ext[0]:5.1f} x {ext[1]:5.1f} x {ext[2]:5.1f} cm  min width {width:5.1f} cm"
                line += _physics(library, info.object_id)
            except AssetError as exc:  # list the rest; say why this one is unusable
                invalid += 1
                line += f"  INVALID: {exc}"
        print(line.rstrip())
    print(f"{len(rows)} objects" + (f", {invalid} invalid" if invalid else ""))
    return 0


def _physics(library, object_id: str) -> str:
    """``  mass 150 g (given)  friction 0.8`` (or ``(500 kg/m^3)`` when the mass comes from a density)."""
    props = library.properties(object_id)
    if props.mass is not None:
        mass, origin = props.mass, "given"
    else:
        mass, origin = props.density * library.processed(object_id).volume, f"{props.density:g} kg/m^3"
    return f"  mass {mass * 1000:6.1f} g ({origin})  friction {props.friction:g}"


def run_prepare(args: argparse.Namespace) -> int:
    """Decompose every selected concave object; exit 1 if any object failed."""
    from ges_core.objects.decompose import DEFAULT, FAST
    from ges_core.objects.prepare import prepare

    settings = FAST if args.coacd == "fast" else DEFAULT
    library = library_from_args(args, coacd=settings)
    entries = [library.entry(user_id(i, args)) for i in args.ids] if args.ids else library.entries()
    entries = entries[: args.limit] if args.limit is not None else entries
    results = prepare(
        entries,
        settings,
        workers=args.workers,
        normalize_size=library.config.normalize_size,
        max_faces=library.config.max_faces,
        progress=not args.no_progress,
    )
    return _report(results)


def _report(results) -> int:
    counts: dict[str, int] = {}
    for r in results:
        counts[r.status] = counts.get(r.status, 0) + 1
    done = [r.seconds for r in results if r.status == "decomposed"]
    timing = f", {sum(done) / len(done):.1f} s per decomposition" if done else ""
    summary = ", ".join(f"{n} {status}" for status, n in sorted(counts.items()))
    print(f"{len(results)} objects: {summary}{timing}")
    for r in results:
        if r.status == "failed":
            print(f"  FAILED {r.object_id}: {r.detail}")
    return 1 if counts.get("failed") else 0

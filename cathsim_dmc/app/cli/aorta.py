"""cathsim-aorta: build a generated aortic arch, import a vessel lumen mesh, or validate an asset.

    cathsim-aorta build arch_type=3 seed=7 name=my_arch out=my_arch
    cathsim-aorta build preset=bovine arch_height_m=0.04           # into the cache; prints the folder
    cathsim-aorta import mesh=lumen.stl units=mm entry=[30,-110,-5] sites.bca=[-27,74,2] sites.lcca=[-1,79,0]
    cathsim-aorta import mesh=slicer.stl units=mm frame=LPS entry=[...] sites.bca=[...]  # a CT segmentation
    cathsim-aorta import mesh=wall.stl caps=[inlet.stl,outlet1.stl] entry=[...] sites.bca=[...]  # a CFD wall
    cathsim-aorta validate my_arch                                 # or a shipped name: type2
    cathsim-aorta list

Arguments are key=value pairs (values in YAML: numbers, [x,y,z] lists, true/false).

build: `preset` (default type1) is the starting point; `arch_type=1|2|3` turns it
  into that clinical type (BCA-origin drop and arch elongation); `seed=N` instead
  draws a random arch from `sample_arch_params` (arch type, size, diameters and, with
  `distribution=morphometry` (the default), how the branches leave the arch;
  `distribution=fixed_branches` keeps the preset's branches; restricted to `arch_type` if
  given); any ArchParams field (e.g.
  arch_height_m=0.04, aneurysm_diameter_m=0.05, bovine=true) is applied last.
  `out=DIR` writes the asset folder DIR (overwrite=true to replace it); without
  `out` it goes into the cache (~/.cache/cathsim_dmc/aortas or
  $CATHSIM_DMC_CACHE/aortas). `validate=false` skips the checks.

import: `mesh=FILE` (STL/OBJ lumen surface), `entry=[x,y,z]` and one or more
  `sites.NAME=[x,y,z]`, all in the mesh's units and frame; without them (`sites=auto`, the
  default) the entry and sites.bca/lcca/lsa are found from the lumen's centerline tree, and
  given ones are checked against the branches found; optional `entry_direction=[x,y,z]`
  (else estimated from the lumen), `units=auto|mm|m`, `frame=sim|LPS|RAS` (the mesh's
  axes; `sim`, the default, is x patient left, y superior, z anterior; CT and 3D Slicer
  exports are LPS), `name=`, `out=DIR`
  (default ./NAME), `wall_mm=2`, `edge_mm=auto`, `sdf_mm=auto`,
  `remesh=auto|true|false`, `open_end_mm=5`, `validate=true`, `overwrite=false`.
  `repair=auto|surface|volume`: `surface` makes only safe repairs to the surface
  as given and refuses what they cannot fix; `volume` rebuilds the lumen from a
  voxel volume (tolerates edges shared by 3+ triangles, self-intersections,
  decimation, gaps up to `close_mm=2`, a wall shell; smooths over `smooth_mm=auto`
  (one voxel); cuts side branches narrower than `trim_mm=3` that lead to no site,
  0 keeps them); `auto` (default) tries `surface`, then `volume`.
  `crop=auto` (default) keeps the lumen within `crop_mm=20` (through the lumen) of
  the entry-to-site paths, past each site too, and caps the rest; `crop=none` keeps
  everything. `caps=[FILE,...]`: cap surfaces of an open (CFD) wall, in its units.
  A surface that folds is remeshed with shorter edges, then a thin septum or ridge crest
  next to the fold is thickened, then the volume smoothed around the fold, then cut away
  there if no path needs it; the import fails with one final line when none of these
  works. Where the septum between two lumens is thinner than the wall, the wall there
  ends halfway across it (a note says where). Every import answers within 240 s: a step
  that spends its budget stops it with one line naming the step.

Exit status 0 on success, 2 with one `error:` line on bad input (including a
mesh that cannot be imported), 1 when `validate` finds problems.
"""

from __future__ import annotations

import pathlib
import sys
from typing import Dict, List, Optional

from cathsim_dmc.app.cli._common import USAGE_ERROR, fail

COMMANDS = ("build", "import", "validate", "list")
BUILD_KEYS = ("preset", "arch_type", "seed", "distribution", "name", "out", "validate", "overwrite")
IMPORT_KEYS = (
    "mesh",
    "entry",
    "sites",
    "entry_direction",
    "units",
    "frame",
    "name",
    "out",
    "wall_mm",
    "edge_mm",
    "sdf_mm",
    "remesh",
    "open_end_mm",
    "validate",
    "overwrite",
    "repair",
    "smooth_mm",
    "close_mm",
    "trim_mm",
    "crop",
    "crop_mm",
    "caps",
)


def _parse_value(text: str):
    import yaml

    try:
        return yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError:
        return text


def parse_pairs(args: List[str], positional_key: Optional[str] = None) -> Dict[str, object]:
    out: Dict[str, object] = {}
    for arg in args:
        if "=" not in arg:
            if positional_key and positional_key not in out:
                out[positional_key] = arg
                continue
            fail(f"argument {arg!r} is not key=value")
        key, _, value = arg.partition("=")
        key = key.strip().lstrip("+")
        if not key:
            fail(f"argument {arg!r} has no key")
        if key in out:
            fail(f"{key} is given twice")
        out[key] = _parse_value(value)
    return out


def _flag(opts, key, default):
    value = opts.pop(key, default)
    if isinstance(value, bool):
        return value
    if str(value).lower() in ("true", "false"):
        return str(value).lower() == "true"
    fail(f"{key}={value!r} is not valid; choose one of ['true', 'false']")


def _size_mb(folder: pathlib.Path) -> float:
    return sum(f.stat().st_size for f in folder.iterdir() if f.is_file()) / 1e6


def cmd_build(args: List[str]) -> int:
    import dataclasses
    import os
    import shutil
    import tempfile

    from cathsim_dmc.anatomy import (
        DISTRIBUTIONS,
        PRESETS,
        ArchParams,
        arch_params,
        build_asset,
        generated_asset,
        load_asset,
        normalize_arch_type,
        sample_arch_params,
        with_arch_type,
    )
    from cathsim_dmc.core.run_files import check_writable_folder

    opts = parse_pairs(args)
    fields = {f.name for f in dataclasses.fields(ArchParams)} - {"name", "arch_type", "seed"}
    unknown = sorted(set(opts) - set(BUILD_KEYS) - fields)
    if unknown:
        fail(
            f"unknown key(s) {unknown} for build; valid: {list(BUILD_KEYS)} or an ArchParams field "
            f"({', '.join(sorted(fields))})"
        )
    preset = str(opts.pop("preset", "type1"))
    if preset not in PRESETS:
        fail(f"preset={preset!r} is not valid; choose one of {list(PRESETS)}")
    validate = _flag(opts, "validate", True)
    overwrite = _flag(opts, "overwrite", False)
    out = opts.pop("out", None)
    name = str(opts.pop("name", "custom"))
    arch_type = opts.pop("arch_type", None)
    seed = opts.pop("seed", None)
    distribution = str(opts.pop("distribution", DISTRIBUTIONS[0]))
    if distribution not in DISTRIBUTIONS:
        fail(f"distribution={distribution!r} is not valid; choose one of {list(DISTRIBUTIONS)}")
    if arch_type is not None:
        arch_type = normalize_arch_type(arch_type)
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            fail(f"seed={seed!r} is not valid; give an integer >= 0")
        types = (arch_type,) if arch_type else ("I", "II", "III")
        params = sample_arch_params(seed, base=preset, arch_types=types, name=name, distribution=distribution)
    else:
        params = PRESETS[preset].replace(name=name)
        if arch_type:
            params = with_arch_type(params, arch_type)
    if opts:
        params = arch_params({**dataclasses.asdict(params), **opts})
    if out is None:
        folder = generated_asset(params)
        print(f"cached in {folder}")
    else:
        folder = check_writable_folder("out", pathlib.Path(str(out)))
        if folder.exists() and any(folder.iterdir()) and not overwrite:
            fail(f"out={str(folder)!r} exists and is not empty; pass overwrite=true or another out")
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
        try:
            build_asset(params, tmp)
            if folder.exists():
                shutil.rmtree(folder)
            os.chmod(tmp, 0o755)
            tmp.rename(folder)
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
    asset = load_asset(folder)
    meta = asset.meta
    ratio = asset.arch_type_distance_m / asset.cca_diameter_m
    tort = meta.get("tortuosity", {})
    print(
        f"{asset.name}: arch type {meta.get('arch_type')} (BCA origin {asset.arch_type_distance_m * 1e3:.1f} mm = "
        f"{ratio:.2f} CCA diameters below the arch top), tortuosity arch {tort.get('arch', float('nan')):.3f} / "
        f"branches {tort.get('branches', float('nan')):.4f}, {meta['counts']['triangles']} triangles, "
        f"{asset.hull_count} wall pieces, {_size_mb(folder):.2f} MB -> {folder}"
    )
    return _report_validation(folder) if validate else 0


def _report_validation(folder) -> int:
    from cathsim_dmc.sim.model_check import validate_and_compile

    report = validate_and_compile(folder)
    print(report.summary())
    for problem in report.problems:
        print(f"  - {problem}")
    return 0 if report.ok else 1


def cmd_import(args: List[str]) -> int:
    from cathsim_dmc.anatomy.importer import import_mesh
    from cathsim_dmc.sim.model_check import validate_and_compile

    opts = parse_pairs(args, positional_key="mesh")
    sites = {k.split(".", 1)[1]: opts.pop(k) for k in list(opts) if k.startswith("sites.")}
    unknown = sorted(set(opts) - set(IMPORT_KEYS))
    if unknown:
        fail(f"unknown key(s) {unknown} for import; valid: {list(IMPORT_KEYS)} and sites.NAME")
    if "mesh" not in opts:
        fail("import needs mesh=...; e.g. cathsim-aorta import mesh=lumen.stl (entry=[x,y,z] sites.bca=[x,y,z])")
    if opts.get("sites", "auto") != "auto" or (sites and "sites" in opts):
        fail(f"sites={opts['sites']!r} is not valid; give sites=auto (the default) or sites.NAME=[x,y,z]")
    opts.pop("sites", None)
    mesh = pathlib.Path(str(opts.pop("mesh")))
    name = str(opts.pop("name", mesh.stem))
    out = pathlib.Path(str(opts.pop("out", name)))

    def mm(key, default):
        value = opts.pop(key, default)
        if value in (None, "auto"):
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
            fail(
                f"{key}={value!r} is not valid; give a positive number of millimetres"
                f"{' or auto' if default == 'auto' else ''}"
            )
        return float(value) * 1e-3

    def mm_or_zero(key, default):
        value = opts.pop(key, default)
        if value in (None, "auto"):
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
            fail(f"{key}={value!r} is not valid; give millimetres (0 or more){' or auto' if default == 'auto' else ''}")
        return float(value) * 1e-3

    from cathsim_dmc.anatomy.frames import FRAMES
    from cathsim_dmc.anatomy.importer import CROP_MODES, DEFAULT_CROP_MARGIN_M, REPAIR_MODES

    frame = str(opts.pop("frame", "sim"))
    if frame not in FRAMES:
        fail(f"frame={frame!r} is not valid; choose one of {list(FRAMES)}")
    repair = str(opts.pop("repair", "auto"))
    if repair not in REPAIR_MODES:
        fail(f"repair={repair!r} is not valid; choose one of {list(REPAIR_MODES)}")
    crop = str(opts.pop("crop", "auto"))
    if crop not in CROP_MODES:
        fail(f"crop={crop!r} is not valid; choose one of {list(CROP_MODES)}")
    crop_margin_m = mm("crop_mm", DEFAULT_CROP_MARGIN_M * 1e3)
    if crop_margin_m < 0.005:
        fail(f"crop_mm={crop_margin_m * 1e3:g} is not valid; give 5 mm or more")
    caps = opts.pop("caps", [])
    caps = [caps] if isinstance(caps, str) else caps
    if not isinstance(caps, list) or not all(isinstance(c, str) for c in caps):
        fail(f"caps={caps!r} is not valid; give a list of mesh files, e.g. caps=[inlet.stl,outlet.stl]")
    for cap in caps:
        if not pathlib.Path(cap).is_file():
            fail(f"caps: {cap} is not a file")

    remesh = opts.pop("remesh", "auto")
    if remesh != "auto":
        remesh = _flag({"remesh": remesh}, "remesh", False)
    report = import_mesh(
        mesh,
        out,
        sites=sites or None,
        entry=opts.pop("entry", None),
        entry_direction=opts.pop("entry_direction", None),
        units=str(opts.pop("units", "auto")),
        frame=frame,
        name=name,
        wall_thickness_m=mm("wall_mm", 2.0),
        edge_length_m=mm("edge_mm", "auto"),
        sdf_spacing_m=mm("sdf_mm", "auto"),
        remesh=remesh,
        open_end_depth_m=mm("open_end_mm", 5.0),
        validate=_flag(opts, "validate", True),
        validator=validate_and_compile,
        overwrite=_flag(opts, "overwrite", False),
        repair=repair,
        smooth_m=mm_or_zero("smooth_mm", "auto"),
        close_gap_m=mm_or_zero("close_mm", 2.0),
        trim_branches_m=mm_or_zero("trim_mm", 3.0),
        crop=crop,
        crop_margin_m=crop_margin_m,
        caps=caps,
    )
    lengths = ", ".join(f"{k} {v * 100:.1f} cm" for k, v in sorted(report.path_length_m.items()))
    print(
        f"{report.name}: {report.triangles} triangles ({'remeshed' if report.remeshed else 'kept'}), "
        f"{report.hulls} wall pieces, entry->site {lengths}, {report.seconds:.1f} s -> {report.path}"
    )
    changes = report.repairs + [n for n in report.notes if n.startswith("a fold at")]
    if changes:  # everything the import changed, and where, in one place
        print(f"{report.name}: changed: " + "; ".join(changes))
    if report.validation is not None:
        print(report.validation.summary())
    return 0


def cmd_validate(args: List[str]) -> int:
    from cathsim_dmc.core.shipped import resolve_asset

    if len(args) != 1:
        fail("validate takes one asset: a folder or a shipped name")
    return _report_validation(resolve_asset(args[0]))


def cmd_list(args: List[str]) -> int:
    from cathsim_dmc.anatomy import load_asset
    from cathsim_dmc.core.shipped import available_aortas, resolve_asset

    if args:
        fail("list takes no arguments")
    print(f"{'name':<16} {'type':<5} {'arch-type distance':<22} {'tortuosity':<11} {'pieces':>6}")
    for name in available_aortas():
        a = load_asset(resolve_asset(name))
        dist = "-"
        if a.arch_type_distance_m is not None and a.cca_diameter_m:
            dist = f"{a.arch_type_distance_m * 1e3:.1f} mm = {a.arch_type_distance_m / a.cca_diameter_m:.2f} CCA"
        tort = a.meta.get("tortuosity", {}).get("arch")
        print(
            f"{name:<16} {a.meta.get('arch_type', '?'):<5} {dist:<22} {'-' if tort is None else f'{tort:.3f}':<11} "
            f"{a.hull_count:>6}"
        )
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print(__doc__)
        return 0 if argv else USAGE_ERROR
    command, rest = argv[0], argv[1:]
    if command not in COMMANDS:
        fail(f"command {command!r} is not valid; choose one of {list(COMMANDS)}")
    from cathsim_dmc.anatomy.importer import MeshImportError

    try:
        return {"build": cmd_build, "import": cmd_import, "validate": cmd_validate, "list": cmd_list}[command](rest)
    except (MeshImportError, ValueError, FileNotFoundError) as error:
        fail(str(error).strip().replace("\n", " "))
    except RuntimeError as error:  # the mesher refusing a geometry
        fail(f"{command} failed: {str(error).strip().splitlines()[0]}")


if __name__ == "__main__":
    sys.exit(main())

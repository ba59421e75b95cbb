"""`warp-hair fit` and `warp-hair targets`: the fitting subcommands, added to the renderer's command line.

    warp-hair fit TARGET -o OUT_DIR [--fit albedo,beta_m,beta_n] [--iters N] [--spp N] [--loss l2]
                  [--lr LR] [--init NAME=V ...] [--fix NAME=V ...] [--seed S] [--patience P] [--refine K] [--threads T]
                  [--device D] [--model-error E] [--export mitsuba,pbrt,cycles,materialx]
    warp-hair targets make [NAME ...] [--threads T]
    warp-hair targets list [NAME ...]
    warp-hair targets check TARGET [--fit NAMES] [--at NAME=V ...] [--spp N] [--model-error E] [--threads T]
    warp-hair batch MANIFEST.toml [-o OUT_DIR] [--address HOST:PORT] [--cpus N] [--cpus-per-job N]

TARGET is a target directory (optimize/target.py describes the layout) or the name of a shipped one in
targets/ (e.g. blonde_straight).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from warp_hair import cli as render_cli
from warp_hair.devices import check_device

from .camera import GAIN_MODES, WHITE_BALANCE_MODES
from .fit import FitSettings
from .identify import CHECK_REALISATION_SAMPLES
from .latents import DEFAULT_FIT, SPECS, as_values
from .realisations import REALISATION_MODES
from .target import fix_controls, resolve_target
from .verdict import FAILED_STATUS


def _bounds_text() -> str:
    """The acceptance bounds as the help states them: "albedo 0.02, beta_m 0.03, ..."."""
    from .settings import BOUNDS

    return ", ".join(f"{name} {bound:g}" for name, bound in BOUNDS.items())


def parse_assignments(items, option: str) -> dict:
    """["albedo=0.5,0.4,0.3", "beta_m=0.4"] → {"albedo": [0.5, 0.4, 0.3], "beta_m": [0.4]}."""
    values = {}
    for item in items or ():
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name or not text:
            raise ValueError(
                f"{option} takes NAME=VALUE (e.g. {option} beta_m=0.4 or {option} albedo=0.6,0.4,0.2), got {item!r}"
            )
        if name not in SPECS:
            raise ValueError(f"{option}: unknown control {name!r}; allowed: {list(SPECS)}")
        try:
            numbers = [float(v) for v in text.split(",")]
        except ValueError:
            raise ValueError(
                f"{option} {name}: {text!r} is not a number or a comma-separated list of numbers"
            ) from None
        values[name] = as_values(name, numbers)
    return values


def add_fit(subparsers) -> None:
    defaults = FitSettings()
    parser = subparsers.add_parser(
        "fit",
        parents=[
            render_cli.common_flags(
                device=True,
                spp=f"samples per pixel at the end of the schedule (default {defaults.spp}; it starts at spp/4)",
                spp_default=defaults.spp,
                seed="seed of the fit's random streams (default 0)",
                seed_default=defaults.seed,
            )
        ],
        help="fit hair controls to a target's images",
        description="Fit hair controls to the images of a target by gradient descent on path-traced renders "
        "(Adam over unconstrained latents, fresh seeds every iteration, growing spp, cosine learning-rate decay), "
        "then Gauss-Newton steps on the linearised loss. "
        "Writes params.json, convergence.png and comparison.png to OUT_DIR and prints fitted vs true controls "
        "when the target has truth.json. Ctrl-C stops early and saves the estimate so far.",
    )
    parser.add_argument(
        "target", metavar="TARGET", help="a target directory, or the name of a shipped target (targets/)"
    )
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="OUT_DIR", help="directory for the results")
    parser.add_argument(
        "--fit",
        default=",".join(DEFAULT_FIT),
        metavar="NAMES",
        help=f"comma-separated controls to fit (default {','.join(DEFAULT_FIT)}); any of {', '.join(SPECS)}",
    )
    parser.add_argument(
        "--iters", type=int, default=defaults.iters, metavar="N", help=f"most iterations (default {defaults.iters})"
    )
    parser.add_argument("--loss", default=defaults.loss, choices=("l2", "rel_l2", "l1"), help="image loss (default l2)")
    parser.add_argument(
        "--lr",
        type=float,
        default=defaults.lr,
        metavar="LR",
        help=f"Adam's initial learning rate on the latents (default {defaults.lr})",
    )
    parser.add_argument(
        "--init",
        nargs="+",
        metavar="NAME=V",
        help="start values of fitted controls (default: albedo 0.5 grey, "
        "beta_m = beta_n = 0.5, the others their usual values)",
    )
    parser.add_argument(
        "--fix", nargs="+", metavar="NAME=V", help="set controls that are not fitted, overriding the scene files"
    )
    parser.add_argument(
        "--patience",
        type=int,
        default=defaults.patience,
        metavar="P",
        help=f"stop after P iterations without improvement at the final spp (default {defaults.patience})",
    )
    parser.add_argument(
        "--refine",
        type=int,
        metavar="K",
        help="Gauss-Newton steps planned after Adam (default 8, or more for a target rendered at more samples "
        "per pixel than 8 steps average; fewer are taken where Adam left the fit settled; 0 with --loss l1, which "
        "is not a sum of squares)",
    )
    parser.add_argument(
        "--batch",
        type=_batch,
        default=defaults.batch,
        metavar="N|all",
        help=f"pixels of an image per render (default {defaults.batch}): a larger image's Adam "
        "iterations render random blocks adding up to N of its pixels, its Gauss-Newton steps all of "
        "them at proportionally fewer samples; 'all' renders every pixel at the full samples",
    )
    parser.add_argument(
        "--model-error",
        type=float,
        metavar="E",
        help="relative brightness disagreement between the target's renderer and warp-hair, counted in "
        "the uncertainties (>= 0; default 0 for warp-hair's own targets, 0.01 for another renderer's "
        "or a target of unknown origin)",
    )
    parser.add_argument(
        "--gains",
        choices=GAIN_MODES,
        help="the images' exposures to fit with the hair (optimize/camera.py): per-image, exif (one "
        "gain, EXIF's t*ISO/N^2 ratios), shared, none (default: target.toml's gains, else per-image "
        "or exif for PNG, JPEG, TIFF and raw photos, none for EXR and linear TIFF)",
    )
    parser.add_argument(
        "--white-balance",
        choices=WHITE_BALANCE_MODES,
        help="fit a white balance (a gain per channel, green's 1) with the hair: fit, none (default: "
        "target.toml's white_balance, else fit for photos, none for EXR and linear TIFF)",
    )
    parser.add_argument(
        "--realisations",
        choices=REALISATION_MODES,
        help="fixed: render the scenes' own fibers; random: they are a recipe (a generator) whose strands are not "
        "the target's, so fit over other realisations of it and count the target's in the uncertainty "
        "(optimize/realisations.py; default: target.toml's realisations, else fixed)",
    )
    parser.add_argument(
        "--export",
        metavar="RENDERERS",
        help="also write the fitted look for these renderers beside params.json (comma-separated: "
        "mitsuba, pbrt, cycles, materialx; files hair_<renderer>.*, as `warp-hair export` writes)",
    )
    parser.set_defaults(run=run_fit)


def _batch(text: str) -> int | None:
    if text == "all":
        return None
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"--batch must be a whole number of pixels >= 1 or 'all', got {text!r}")
    return value


def run_fit(args: argparse.Namespace) -> int:
    from .camera import fitted as fitted_camera
    from .card_region import summary as card_summary
    from .fit import fit
    from .report import arrangement_table, camera_table, describe_run, format_table, photo_summary, write_outputs
    from .target import load_target, true_values

    render_cli.check_sampling_args(args)
    from warp_hair.export import parse_renderers

    from .uncertainty import check_model_error

    check_model_error(args.model_error, "--model-error")
    device = check_device(args.device, "--device")

    # Checked before the fit, not after it.
    renderers = [] if args.export is None else parse_renderers(args.export)
    target = load_target(resolve_target(args.target))
    names = [n.strip() for n in args.fit.split(",") if n.strip()]
    fixed = parse_assignments(args.fix, "--fix")
    both = sorted(set(fixed) & set(names))
    if both:
        raise ValueError(f"control(s) {both} are both fixed (--fix) and fitted (--fit); choose one")
    if fixed:
        fix_controls(target, fixed)
    _set_camera_unknowns(target, args)
    settings = FitSettings(
        controls=tuple(names),
        iters=args.iters,
        spp=args.spp,
        loss=args.loss,
        lr=args.lr,
        seed=args.seed,
        patience=args.patience,
        init=parse_assignments(args.init, "--init"),
        threads=args.threads,
        device=device,
        refine=args.refine,
        batch=args.batch,
        model_error=args.model_error,
        realisations=args.realisations,
    )
    sizes = ", ".join(f"{im.name} {im.image.shape[1]}x{im.image.shape[0]}" for im in target.images)
    camera = (
        ""
        if not fitted_camera(target)
        else (f", with the photos' gains ({target.gains}) and white balance ({target.white_balance})")
    )
    print(f"fitting {', '.join(names)} of {target.name} ({sizes}){camera}")
    for line in photo_summary(target) + card_summary(target):
        print(f"  {line}")
    result = fit(target, settings)
    if result.stop_reason == "interrupted":
        print("interrupted: saving the estimate so far (no uncertainties)")
    paths = write_outputs(args.output, result, target, settings, progress=True)
    paths += _export(args.output / "params.json", renderers)
    print(format_table(result, true_values(target, result.values), target.origin))
    if result.camera is not None:
        print(camera_table(result))
    if result.arrangement is not None:
        print(arrangement_table(result))
    run = describe_run(result.iterations, result.stop_reason, result.history.refine)
    print(f"{run}, {result.seconds:.0f} s, final loss {result.loss:.4g}")
    if result.goodness is not None:
        print("\n".join(result.goodness.lines()))
    for warning in result.warnings:
        print(f"{render_cli.PROG}: warning: {warning}", file=sys.stderr)
    print("wrote " + ", ".join(str(p) for p in paths))
    if result.failed:
        # A failed fit's numbers are no result: said as a failure, with a status a script can tell (verdict.py).
        for reason in result.failures:
            print(f"{render_cli.PROG}: fit failed: {reason}", file=sys.stderr)
        print(
            f"{render_cli.PROG}: the fit of {target.name} FAILED: the values above are not a result "
            f"(params.json says failed)",
            file=sys.stderr,
        )
        return FAILED_STATUS
    return 0


def _set_camera_unknowns(target, args) -> None:
    """--gains / --white-balance override target.toml's (or the default the images give, target.py)."""
    from .camera import relative_exposures

    if args.gains is not None:
        target.gains = args.gains
    if args.white_balance is not None:
        target.white_balance = args.white_balance
    if target.gains == "exif":
        missing = [im.image_path.name for im in target.images if im.relative_exposure is None]
        if missing:
            raise ValueError(
                f"--gains exif: {', '.join(missing)} has no EXIF exposure time, f-number and ISO; use --gains per-image"
            )
        relative_exposures(target)


def _export(params_json: Path, renderers) -> list[Path]:
    from warp_hair.export import default_filename, export

    paths = [params_json.parent / default_filename(name) for name in renderers]
    for name, path in zip(renderers, paths):
        export(params_json, to=name, path=path)
    return paths


def add_targets(subparsers) -> None:
    parser = subparsers.add_parser(
        "targets",
        parents=[render_cli.common_flags(threads=False)],
        help="list, regenerate or check the fit targets",
        description="list: the shipped targets and their true controls; make: render each target's images from "
        "its scene files (at their [render] spp and seed) and write truth.json, reproducing the committed files; "
        "check: whether a target's images identify its controls (exit status 1 when they do not).",
    )
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    names_help = "shipped target names or target directories (default: all shipped)"
    listing = actions.add_parser(
        "list",
        parents=[render_cli.common_flags(threads=False)],
        help="the shipped targets, their truth and who rendered them",
    )
    listing.add_argument("names", nargs="*", metavar="NAME", help=names_help)
    make = actions.add_parser(
        "make", parents=[render_cli.common_flags()], help="re-render warp-hair's targets from their scene files"
    )
    make.add_argument("names", nargs="*", metavar="NAME", help=names_help)
    check = actions.add_parser(
        "check",
        parents=[
            render_cli.common_flags(
                spp="samples per pixel the target's noise is taken at (default: its scenes' [render] spp, what it "
                "was rendered with); to see what more samples would give",
                spp_default=None,
            )
        ],
        help="whether a target's images identify its controls",
        description="Linearise the fit's loss at the target's true controls (truth.json, or --at) and print, per "
        "fitted control, the 1-sigma the target's own noise leaves (its Fisher information: our render's noise "
        "at the target's spp), the shift of the estimate were the target 1% brighter (another renderer's "
        "disagreement), the fit's own Monte Carlo error (the mean of its Gauss-Newton points, each from renders "
        "at its samples), the expected sigma of all three (the model error as the fit counts it: 0 for "
        "warp-hair's own targets, 1% for others) and the largest correlation with another control. Identifiable "
        f"when every control's expected sigma is below its acceptance bound ({_bounds_text()}), "
        "and pinned where twice it is (a fit lands within the bound about 19 times in 20); else exit status 1, "
        "naming the control and what to add. For photos (whose gains and white balance are fitted, "
        "optimize/camera.py) it also says which of those the images pin. Costs 8 renders of each image at 64 spp.",
    )
    check.add_argument("target", metavar="TARGET", help="a target directory, or the name of a shipped target")
    check.add_argument(
        "--fit",
        default=",".join(DEFAULT_FIT),
        metavar="NAMES",
        help=f"the controls a fit would fit (default {','.join(DEFAULT_FIT)})",
    )
    check.add_argument(
        "--at",
        nargs="+",
        metavar="NAME=V|PARAMS",
        help="check at these values instead of truth.json's (a photo has none): NAME=V, or a fit's params.json (or "
        "its directory) for the look it fitted, a quick fit's estimate; NAME=V given with it override its values",
    )
    check.add_argument(
        "--realisation-samples",
        type=int,
        default=CHECK_REALISATION_SAMPLES,
        metavar="K",
        help=f"with --realisations random: the further realisations the strands' draw part comes from (default "
        f"{CHECK_REALISATION_SAMPLES}; its uncertainty falls about as 1/sqrt(2(K-1)))",
    )
    check.add_argument(
        "--refine",
        type=int,
        metavar="K",
        help="count the own Monte Carlo error of a fit with K Gauss-Newton steps (default: as `fit` would run, "
        "8 or more)",
    )
    check.add_argument(
        "--model-error",
        type=float,
        metavar="E",
        help="relative brightness disagreement to count (default as the fit: 0 for warp-hair's own "
        "targets, 0.01 for others)",
    )
    check.add_argument(
        "--realisations",
        choices=REALISATION_MODES,
        help="random: the scenes' fibers are a recipe whose strands are not the target's, so count how far the "
        "target's strands, one draw of it, move the estimate (--realisation-samples more linearisations, two "
        "renders of each image each); "
        "fixed: the scenes hold the very strands (default: target.toml's realisations, else fixed)",
    )
    _add_photo(actions)
    for sub in (listing, make, check):
        sub.set_defaults(run=run_targets)


def _vector(text: str) -> tuple:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(v == v and abs(v) != float("inf") for v in values) or not any(values):
        raise argparse.ArgumentTypeError(f"a direction is three numbers X,Y,Z, not all 0, got {text!r}")
    return values


def _add_photo(actions) -> None:
    from warp_hair.photo import TRANSFERS

    photo = actions.add_parser(
        "photo",
        parents=[render_cli.common_flags(threads=False)],
        help="make a target from photographs of a swatch or fur patch",
        description="Write a target directory from photos: each decoded to linear and box-filtered to --resolution, "
        "a scene per photo (the rig, the camera, its light), a mask of the clipped, crushed and background "
        "pixels, and target.toml with the photos' gains and white balance to fit (optimize/photo_target.py). "
        "Then: warp-hair fit OUT_DIR -o FIT_DIR.",
    )
    photo.add_argument("output", type=Path, metavar="OUT_DIR", help="the target directory to write")
    photo.add_argument(
        "--rig",
        choices=("draped", "flat", "fur"),
        default="draped",
        help="a swatch draped over a rod (default), a flat swatch on a card, a fur patch",
    )
    photo.add_argument(
        "--image",
        action="append",
        required=True,
        metavar="PHOTO",
        help="a photo (PNG, JPEG, TIFF, or camera raw with the photo extra); repeat for each view",
    )
    photo.add_argument(
        "--light",
        action="append",
        type=_vector,
        metavar="X,Y,Z",
        help="per --image, in order: the direction its directional light travels, in the rig's frame "
        "(x across, y along the fibers, z towards the camera)",
    )
    photo.add_argument(
        "--hdri",
        metavar="EXR",
        help="a lat-long EXR taken where the swatch stood, for every view, in the rig's frame (+y up the image, "
        "u = 0 looking away from the camera); with --light, those directional lights as well",
    )
    photo.add_argument(
        "--transfer", choices=TRANSFERS, default="auto", help="the photos' transfer curve (default auto)"
    )
    photo.add_argument(
        "--width", type=float, default=0.4, help="swatch width across the fibers (scene units, default 0.4)"
    )
    photo.add_argument("--length", type=float, default=0.5, help="swatch length along the fibers (default 0.5)")
    photo.add_argument("--count", type=int, default=152, help="fibers (default 152)")
    photo.add_argument("--layers", type=int, default=4, help="layers of fibers (default 4)")
    photo.add_argument("--fiber-radius", type=float, default=0.004, help="fiber radius (default 0.004)")
    photo.add_argument("--drape", type=float, default=0.25, help="the rod's radius, draped rig (default 0.25)")
    shape = photo.add_mutually_exclusive_group()
    shape.add_argument(
        "--waves",
        type=_pair("AMPLITUDE,WAVELENGTH"),
        metavar="AMPLITUDE,WAVELENGTH",
        help="wavy fibers (the wavy generator): half their peak-to-peak swing and the length of a wave, scene units",
    )
    shape.add_argument(
        "--curls",
        type=_pair("RADIUS,PITCH"),
        metavar="RADIUS,PITCH",
        help="curly fibers (the curly generator): the helix's radius and its rise per turn, scene units",
    )
    photo.add_argument(
        "--phase-jitter",
        type=float,
        metavar="F",
        help="with --waves or --curls: how independent the fibers' waves are, 0 (in step: combed) to 1 "
        "(default: the generator's, 0.15 for waves, 1 for curls)",
    )
    photo.add_argument(
        "--layer-phase-jitter",
        type=float,
        metavar="F",
        help="with --waves or --curls: how independent the layers' waves are, 0 (default: in step) to 1 (a "
        "swatch combed layer by layer)",
    )
    photo.add_argument("--clumps", type=int, metavar="N", help="swatch rigs: the fibers gather into N clumps")
    photo.add_argument(
        "--clump-strength",
        type=float,
        metavar="S",
        help="with --clumps: how far a clump's fibers are pulled to its guide at the tips, 0 to 1 (default 0.5)",
    )
    photo.add_argument(
        "--strays", type=int, metavar="N", help="swatch rigs: N fibers of the front layer leave its surface"
    )
    photo.add_argument(
        "--stray-lift",
        type=float,
        metavar="L",
        help="with --strays: the highest a stray's tip rises off the surface, scene units (default length / 10)",
    )
    photo.add_argument("--patch", type=float, default=0.3, help="fur patch size (default 0.3)")
    photo.add_argument("--fur-length", type=float, default=0.1, help="fur length (default 0.1)")
    photo.add_argument("--elevation", type=float, default=30.0, help="fur rig: camera's degrees above the patch (30)")
    photo.add_argument("--distance", type=float, default=3.0, help="camera distance from the rig's centre (default 3)")
    lens = photo.add_mutually_exclusive_group()
    lens.add_argument("--ortho-width", type=float, help="an orthographic camera of this view width (scene units)")
    lens.add_argument("--fov", type=float, help="perspective: horizontal field of view, degrees")
    photo.add_argument(
        "--sensor-width", type=float, help="perspective: sensor width in mm, with the photo's EXIF focal length"
    )
    photo.add_argument("--resolution", type=int, default=64, help="pixels across of the target's images (default 64)")
    photo.add_argument(
        "--card",
        type=float,
        metavar="REFLECTANCE",
        help="a grey card behind the swatch, of this reflectance (e.g. 0.18), rendered as its [card]",
    )
    photo.add_argument(
        "--mask",
        nargs="+",
        metavar="auto|FILE",
        help="'auto': leave out the background (not with --card); or a mask per photo (white = counts)",
    )
    photo.add_argument(
        "--card-mask",
        nargs="+",
        metavar="FILE|none",
        help="a grey card in the photos, nobody modelled: per --image, in order, a mask of its pixels (white = "
        "the card, at the photo's size) or 'none'; it pins the gains and white balance (optimize/card_region.py)",
    )
    photo.add_argument(
        "--card-reflectance",
        type=_reflectance,
        metavar="R|R,G,B",
        help="the masked card's reflectance, each in (0, 1] (an 18%% grey card: 0.18; per channel from its datasheet)",
    )
    photo.add_argument(
        "--card-normal",
        type=_card_normal,
        default="camera",
        metavar="camera|X,Y,Z",
        help="the masked card's normal in the rig's frame, or 'camera' (facing it, the default)",
    )
    photo.add_argument(
        "--gains",
        choices=("per-image", "exif"),
        default="per-image",
        help="the photos' exposures: per-image (the default: a gain each), or exif (one gain, the views' ratios "
        "from their EXIF: where one lamp, as strong in every view, lit them all)",
    )
    photo.set_defaults(run=run_photo)


def _pair(names: str):
    """An argparse type: two numbers A,B, as `names` calls them."""

    def parse(text: str) -> tuple:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) != 2:
            raise argparse.ArgumentTypeError(f"expected two numbers {names}, got {text!r}")
        return values

    return parse


def _reflectance(text: str) -> float | list:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) not in (1, 3) or not all(0 < v <= 1 for v in values):
        raise argparse.ArgumentTypeError(f"a reflectance is R or R,G,B, each in (0, 1], got {text!r}")
    return values[0] if len(values) == 1 else values


def _card_normal(text: str) -> str | list:
    return "camera" if text == "camera" else list(_vector(text))


def run_photo(args: argparse.Namespace) -> int:
    from .photo_target import make_photo_target

    written = make_photo_target(args.output, args, log=print)
    print(
        f"wrote {', '.join(p.name for p in written)} to {args.output}; fit it with "
        f"`warp-hair fit {args.output} -o {args.output}_fit`"
    )
    return 0


def run_targets(args: argparse.Namespace) -> int:
    from .target import load_target, made_by, make_target, shipped_targets, target_renderer

    render_cli.check_sampling_args(args)
    if args.action == "check":
        return _check_target(args)
    directories = [resolve_target(n) for n in args.names] if args.names else shipped_targets()
    for directory in directories:
        if args.action == "list":
            target = load_target(directory)
            truth = "" if target.truth is None else " ".join(f"{k}={v}" for k, v in target.truth.to_dict().items())
            by = "" if target.origin == "warp-hair" else f" ({made_by(target.origin)})"
            print(f"{directory.name}: {', '.join(im.name for im in target.images)}{by}; {truth}")
            continue
        if not args.names and target_renderer(directory) != "warp-hair":
            print(
                f"{directory.name}: rendered by {target_renderer(directory)}, left as it is "
                "(benchmarks/make_peer_targets.py re-renders it)"
            )
            continue
        start = time.perf_counter()
        with render_cli.progress_bar(unit="px", desc=f"make {directory.name}") as progress:
            written = make_target(directory, threads=args.threads, progress=progress)
        print(f"{directory.name}: wrote {', '.join(p.name for p in written)} ({time.perf_counter() - start:.0f} s)")
    return 0


def _check_values(items, names) -> dict:
    """--at's values: a fit's params.json (or its directory), its look's values of the checked controls `names`,
    and NAME=V items, which override them."""
    values = {}
    for item in items or ():
        if "=" in item:
            continue
        path = Path(item) / "params.json" if Path(item).is_dir() else Path(item)
        try:
            look = json.loads(path.read_text(encoding="utf-8"))["look"]
        except (OSError, ValueError, KeyError, TypeError) as error:
            reason = "it has no look" if isinstance(error, (KeyError, TypeError)) else error
            raise ValueError(
                f"--at {item}: not NAME=V and not a fit's params.json (or its directory) to read a look from: {reason}"
            ) from None
        values.update({name: look[name] for name in names if name in look})
    values.update(parse_assignments([item for item in items or () if "=" in item], "--at"))
    return values


def _check_target(args: argparse.Namespace) -> int:
    from .card_region import summary as card_summary
    from .identify import check_target, describe
    from .latents import parse_control_names
    from .target import load_target
    from .uncertainty import check_model_error

    check_model_error(args.model_error, "--model-error")
    if args.refine is not None and args.refine < 1:
        raise ValueError(f"--refine must be at least 1 for a check, got {args.refine}")
    target = load_target(resolve_target(args.target))
    names = [n.strip() for n in args.fit.split(",") if n.strip()]
    start = time.perf_counter()
    result = check_target(
        target,
        _check_values(args.at, parse_control_names(names, target.hair.colour_input)),
        names,
        spp=args.spp,
        model_error=args.model_error,
        threads=args.threads,
        realisations=args.realisations,
        settings=FitSettings(controls=parse_control_names(names, target.hair.colour_input), refine=args.refine),
        realisation_samples=args.realisation_samples,
    )
    for line in card_summary(target):
        print(line)
    print(describe(result))
    print(f"({time.perf_counter() - start:.0f} s)")
    if not result.identifiable:
        print(
            f"{render_cli.PROG}: {target.name} is a bad target: its images do not pin down "
            f"{', '.join(p.split(':')[0] for p in result.problems)}",
            file=sys.stderr,
        )
        return 1
    return 0


def add_batch(subparsers) -> None:
    parser = subparsers.add_parser(
        "batch",
        parents=[render_cli.common_flags(threads=False)],
        help="run a manifest of fits, renders and calibrations on a Ray cluster",
        description="Run the fits, renders and calibrations a manifest lists (optimize/batch/manifest.py describes "
        "it) as Ray tasks: on a Ray started on this machine, or on the cluster at --address. Each job's results are "
        "written beside the manifest as it finishes; a rerun skips finished jobs; Ctrl-C keeps what finished. "
        "Writes summary.csv, summary.json and report.html. Exit status 1 when a job failed. Needs the cluster "
        'extra: pip install -e ".[cluster]".',
    )
    parser.add_argument("manifest", type=Path, metavar="MANIFEST.toml", help="the manifest")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="OUT_DIR",
        help="the results' folder (default: the manifest's [batch] output, else <stem>_out beside it)",
    )
    parser.add_argument(
        "--address",
        metavar="HOST:PORT",
        help="join the Ray cluster whose head is there (it must check Ray's auth tokens; docs/cluster.md) "
        "(default: RAY_ADDRESS, else a Ray of the batch's own on this machine, reachable from it only)",
    )
    parser.add_argument(
        "--cpus", type=int, metavar="N", help="CPUs of the Ray the batch starts here (default: all cores)"
    )
    parser.add_argument(
        "--cpus-per-job",
        type=int,
        metavar="N",
        help="CPUs (and Warp threads) each job declares (default: the manifest's [batch] cpus_per_job, else 1)",
    )
    parser.set_defaults(run=run_batch_command)


def run_batch_command(args: argparse.Namespace) -> int:
    from .batch import load_manifest, run_batch

    for option in ("cpus", "cpus_per_job"):
        value = getattr(args, option)
        if value is not None and value < 1:
            raise ValueError(f"--{option.replace('_', '-')} must be a whole number >= 1, got {value}")
    manifest = load_manifest(args.manifest, args.output)
    if args.cpus_per_job is not None:
        manifest.cpus_per_job = args.cpus_per_job
    outcome = run_batch(manifest, address=args.address, cpus=args.cpus)
    retried = f" ({len(outcome.retried)} retried after a worker died)" if outcome.retried else ""
    print(
        f"{len(outcome.done)} done, {len(outcome.skipped)} finished earlier, {len(outcome.failed)} failed{retried}; "
        f"wrote {manifest.output / 'summary.csv'}, {manifest.output / 'report.html'}"
    )
    for name in outcome.failed:
        from .batch import store

        status = store.read_status(manifest.output, name) or {}
        print(f"{render_cli.PROG}: {name} failed: {status.get('error', '?')}", file=sys.stderr)
    return 1 if outcome.failed else 0


def main(argv: list[str] | None = None) -> int:
    return render_cli.main(argv, extra=(add_fit, add_targets, add_batch))


if __name__ == "__main__":
    sys.exit(main())

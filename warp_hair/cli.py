"""The `warp-hair` command line.

Each subcommand is an `add_*` function that declares its arguments and a function that runs it; the work
itself lives in the library. Bad input (a control out of range, an unwritable path) ends with
`warp-hair: error: <message>` on stderr and exit status 2, as argparse does for malformed arguments; Ctrl-C
with one line and exit status 130, leaving no partial output file; anything else (a bug) with a short message,
and its traceback under `--debug`. Warp's own messages (its banner, each module it loads, its "no CUDA driver"
line on a machine without a GPU) are left out; `--verbose` shows them.

    warp-hair plot-bsdf -o lobes.png [hair controls] [--theta-o DEG ...] [--h H]
    warp-hair render SCENE.toml -o OUT.exr [--spp N] [--seed S] [--threads T] [--device D] [--png PREVIEW.png]
    warp-hair gradcheck SCENE.toml [--spp N] [--seeds K] [--params albedo,eta,...] [--eps E] [--threads T]
    warp-hair export LOOK --to mitsuba|pbrt|cycles|materialx [-o FILE]
    warp-hair calibrate SCENE.toml [-o COPY.toml] [--sigma-a S ...] [--beta-n B ...] [--spp N] [--seed S] [--threads T]

and, added by optimize/cli.py, `warp-hair fit` and `warp-hair targets list|make|check`.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import traceback
import warnings
from pathlib import Path

import warp as wp

from . import validate
from .controls import COLOUR_CONTROL_NAMES, COLOUR_CONTROLS, CONTROLS
from .devices import DEFAULT_DEVICE, check_device, init_warp
from .model.params import HairParams
from .parallel import interrupts_delivered

PROG = "warp-hair"
DEFAULT_ALBEDO = (0.6, 0.4, 0.2)
SCENE_SPP = "samples per pixel (default: the scene's [render] spp)"
SCENE_SEED = "random seed (default: the scene's [render] seed)"


def common_flags(
    *, threads=True, device=False, spp=None, seed=None, spp_default=None, seed_default=None
) -> argparse.ArgumentParser:
    """The parent parser of a subcommand: the flags every command spells the same way.

    --debug and --verbose (also accepted before the subcommand), --threads where the command renders, --device
    where it can render on a GPU, and --spp / --seed where given their help text (the defaults differ: the scene's
    [render] table, or the command's own).
    """
    parent = argparse.ArgumentParser(add_help=False)
    if spp is not None:
        parent.add_argument("--spp", type=int, default=spp_default, metavar="N", help=spp)
    if seed is not None:
        parent.add_argument("--seed", type=int, default=seed_default, metavar="S", help=seed)
    if threads:
        parent.add_argument("--threads", type=int, metavar="T", help="CPU threads (default: all cores)")
    if device:
        parent.add_argument(
            "--device",
            default=DEFAULT_DEVICE,
            metavar="D",
            help="where to render: cpu (the default), cuda or cuda:N (a GPU, through Warp's CUDA backend)",
        )
    # SUPPRESS keeps the top-level value when the flag is not repeated after the subcommand.
    parent.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    parent.add_argument("--verbose", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    return parent


def add_hair_controls(parser: argparse.ArgumentParser) -> None:
    """One flag per control of the table (`warp_hair.controls`), its help the table's range, unit and doc."""
    inputs = " or ".join("/".join(f"--{flag(name)}" for name in names) for names in COLOUR_CONTROLS.values())
    group = parser.add_argument_group(
        "hair controls",
        f"Colour: one of {inputs} (default --albedo {' '.join(f'{c:g}' for c in DEFAULT_ALBEDO)}).",
    )
    for name, c in CONTROLS.items():
        where = f"in {c.interval}" + (f" ({c.unit})" if c.unit else "")
        if c.size == 3:
            group.add_argument(
                f"--{flag(name)}",
                nargs="+",
                type=float,
                metavar="X",
                help=f"{c.doc}; {where}: one value (grey) or three (R G B)",
            )
        elif c.colour_input is not None:  # unset unless given: the colour input is the one given
            group.add_argument(f"--{flag(name)}", type=float, metavar="X", help=f"{c.doc}; {where}")
        else:
            group.add_argument(
                f"--{flag(name)}",
                type=float,
                default=c.default,
                metavar="X",
                help=f"{c.doc}; {where} (default {c.default:g})",
            )


def flag(name: str) -> str:
    """A control's command-line flag, without the dashes: beta_m → beta-m."""
    return name.replace("_", "-")


def hair_params(args: argparse.Namespace) -> HairParams:
    controls = {name: getattr(args, name) for name in CONTROLS}
    if all(controls[name] is None for name in COLOUR_CONTROL_NAMES):
        controls["albedo"] = DEFAULT_ALBEDO
    return HairParams(**controls)


def add_plot_bsdf(subparsers) -> None:
    parser = subparsers.add_parser(
        "plot-bsdf",
        parents=[common_flags(threads=False)],
        help="plot the lobes of a hair material to a PNG",
        description="Plot the azimuthal (top row) and longitudinal (bottom row) lobes of a hair material, "
        "one column per viewing angle, for checking a material by eye.",
    )
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="PNG", help="the PNG file to write")
    add_hair_controls(parser)
    parser.add_argument(
        "--theta-o",
        nargs="+",
        type=float,
        default=[0.0, 30.0, 60.0],
        metavar="DEG",
        help="viewing angles from the fiber's normal plane, in (-90, 90) (default 0 30 60)",
    )
    parser.add_argument(
        "--h", type=float, metavar="H", help="fiber offset in [-1, 1] (default: averaged over h, the far-field look)"
    )
    parser.set_defaults(run=plot_bsdf)


def plot_bsdf(args: argparse.Namespace) -> None:
    from .plot import plot_lobes  # matplotlib is needed by this command only

    print(plot_lobes(hair_params(args), args.output, theta_o_deg=args.theta_o, h=args.h))


def add_render(subparsers) -> None:
    parser = subparsers.add_parser(
        "render",
        parents=[common_flags(device=True, spp=SCENE_SPP, seed=SCENE_SEED)],
        help="path-trace a scene file to a linear EXR",
        description="Path-trace a scene (TOML) to a float32 linear-radiance EXR, with the scene and hair controls "
        "in its header; optionally also a tone-mapped sRGB PNG preview.",
    )
    parser.add_argument("scene", type=Path, metavar="SCENE.toml", help="the scene file")
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="OUT.exr", help="the EXR file to write")
    parser.add_argument("--png", type=Path, metavar="PREVIEW.png", help="also write a tone-mapped sRGB preview")
    parser.add_argument(
        "--exposure", type=float, default=1.0, metavar="E", help="scale applied before tone mapping the PNG (default 1)"
    )
    parser.set_defaults(run=render_scene)


def render_scene(args: argparse.Namespace) -> None:
    import time

    from .io import write_exr, write_png
    from .renderer.render import render, render_metadata
    from .scene import load_scene

    check_sampling_args(args)
    device = check_device(args.device, "--device")
    if args.png is not None:
        validate.real("--exposure", args.exposure)
        if not args.exposure > 0:
            raise ValueError(f"--exposure must be > 0, got {args.exposure!r}")
    scene = load_scene(args.scene)
    spp = scene.render.spp if args.spp is None else args.spp
    seed = scene.render.seed if args.seed is None else args.seed
    width, height = scene.camera.resolution
    start = time.perf_counter()
    with progress_bar(
        total=width * height, unit="px", desc=f"{args.scene.name} {width}x{height} {spp} spp"
    ) as progress:
        image = render(scene, spp=spp, seed=seed, threads=args.threads, device=device, progress=progress)
    seconds = time.perf_counter() - start
    write_exr(args.output, image, render_metadata(scene, spp, seed))
    print(f"wrote {args.output} ({seconds:.1f} s, {width * height * spp / seconds / 1e6:.3f} M paths/s)")
    if args.png is not None:
        write_png(args.png, image, exposure=args.exposure)
        print(f"wrote {args.png}")


def add_gradcheck(subparsers) -> None:
    parser = subparsers.add_parser(
        "gradcheck",
        parents=[common_flags(spp="samples per pixel per render (default 16)", spp_default=16)],
        help="check render gradients against finite differences on a scene",
        description="Compare the render-level gradients (render_grad) of L = mean 0.5 (image - target)^2 with "
        "central finite differences of render (common random numbers, Richardson-extrapolated from eps and "
        "eps/2), over K seed pairs, one row per control component. The target is the scene rendered at 16x "
        f"the spp with the checked controls moved ({_gradcheck_moves()}). Cost: about (2 + 8 x components) x K "
        "renders at --spp plus the target, at the scene's own resolution; lower the resolution in the scene for quick "
        "checks.",
    )
    parser.add_argument("scene", type=Path, metavar="SCENE.toml", help="the scene file")
    parser.add_argument(
        "--seeds",
        type=int,
        default=4,
        metavar="K",
        help="independent seed pairs, for the standard errors; at least 2 (default 4)",
    )
    parser.add_argument(
        "--params",
        metavar="NAMES",
        help="comma-separated controls to check, e.g. albedo,beta_m (default: all of the scene's)",
    )
    parser.add_argument(
        "--eps",
        type=float,
        metavar="E",
        help="one finite-difference step for every control (default per control: "
        + ", ".join(f"{name} {c.gradcheck_step:g}" for name, c in CONTROLS.items())
        + ")",
    )
    parser.set_defaults(run=gradcheck_scene)


def _gradcheck_moves() -> str:
    """How gradcheck's target moves each control, from the table: "albedo x0.9, ..., eta +0.05, ..."."""
    return ", ".join(
        f"{name} {'x' if kind == 'scale' else '+'}{amount:g}"
        for name, c in CONTROLS.items()
        for kind, amount in [c.gradcheck_move]
    )


def check_sampling_args(args: argparse.Namespace) -> None:
    """The options that reach the kernels as int32 or uint32, checked as the scene file's [render] table is."""
    if getattr(args, "spp", None) is not None:
        validate.integer("--spp", args.spp, minimum=1)
    if getattr(args, "seed", None) is not None:
        validate.seed("--seed", args.seed)
    if getattr(args, "threads", None) is not None:
        validate.integer("--threads", args.threads, minimum=1, maximum=4096)


def gradcheck_scene(args: argparse.Namespace) -> None:
    from .gradcheck import format_table, gradcheck
    from .scene import load_scene

    check_sampling_args(args)
    scene = load_scene(args.scene)
    names = None if args.params is None else args.params.split(",")
    width, height = scene.camera.resolution
    with progress_bar(unit="render", desc=f"{args.scene.name} {width}x{height} {args.spp} spp") as progress:
        rows = gradcheck(
            scene, names, spp=args.spp, seeds=args.seeds, eps=args.eps, threads=args.threads, progress=progress
        )
    print(format_table(rows))
    bad = [row.control for row in rows if not row.ok]
    print(f"{len(rows) - len(bad)}/{len(rows)} OK" + (f"; mismatched: {', '.join(bad)}" if bad else ""))


def add_export(subparsers) -> None:
    from .export import RENDERERS

    parser = subparsers.add_parser(
        "export",
        parents=[common_flags(threads=False)],
        help="write a look for Mitsuba 3, pbrt-v4, Blender Cycles or MaterialX",
        description="Convert a look to another renderer's hair material: Mitsuba 3's hair BSDF (XML element), "
        'pbrt-v4\'s Material "hair", a Blender bpy script building a Principled Hair BSDF (Chiang), or a '
        "MaterialX document with chiang_hair_bsdf. Controls a renderer cannot express are reported as warnings.",
    )
    parser.add_argument(
        "look",
        type=Path,
        metavar="LOOK",
        help="a fit's params.json, a JSON object of controls (truth.json), or a scene file ([hair])",
    )
    parser.add_argument("--to", required=True, metavar="RENDERER", help=f"one of {', '.join(RENDERERS)}")
    parser.add_argument(
        "-o", "--output", type=Path, metavar="FILE", help="the file to write (default: standard output)"
    )
    parser.set_defaults(run=export_look)


def export_look(args: argparse.Namespace) -> None:
    from .export import export

    text = export(args.look, to=args.to, path=args.output)
    if args.output is None:
        sys.stdout.write(text)
    else:
        print(f"wrote {args.output}")


def add_calibrate(subparsers) -> None:
    parser = subparsers.add_parser(
        "calibrate",
        parents=[
            common_flags(
                spp=SCENE_SPP, seed="seed of the first render, the k-th uses S + k (default: the scene's [render] seed)"
            )
        ],
        help="refit the albedo inversion for a scene's assembly and lighting",
        description="Render the scene at every point of a grid of grey sigma_a and beta_n (its other controls as "
        "they are), measure each render's albedo (the mean of the pixels the fibers cover, over the radiance of a "
        "white Lambertian card facing the camera under the same lights), fit ln c = -sqrt(sigma_a) P(beta_n) with "
        "P of degree 5 by weighted least squares, and print the coefficients, the residuals and the "
        "[hair.albedo_inversion] table that makes HairParams use them. The scene file is never changed.",
    )
    parser.add_argument("scene", type=Path, metavar="SCENE.toml", help="the scene file (assembly, lights, camera)")
    parser.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="COPY.toml",
        help="write a copy of the scene with the fitted [hair.albedo_inversion] table",
    )
    parser.add_argument(
        "--sigma-a",
        nargs="+",
        type=float,
        metavar="S",
        help="grey absorptions of the grid, > 0 (default: warp_hair.calibrate.DEFAULT_SIGMA_A, "
        "5 values; the grid is printed)",
    )
    parser.add_argument(
        "--beta-n",
        nargs="+",
        type=float,
        metavar="B",
        help="azimuthal roughnesses of the grid, in [0.01, 1], at least 6 distinct (default: "
        "warp_hair.calibrate.DEFAULT_BETA_N, 8 values)",
    )
    parser.set_defaults(run=calibrate_scene)


def calibrate_scene(args: argparse.Namespace) -> None:
    from .calibrate import (
        DEFAULT_BETA_N,
        DEFAULT_SIGMA_A,
        calibrate,
        check_copy_path,
        check_grid,
        inversion_toml,
        write_calibrated_scene,
    )
    from .renderer.prepare import sampling
    from .scene import load_scene

    sigma_a, beta_n = check_grid(args.sigma_a or DEFAULT_SIGMA_A, args.beta_n or DEFAULT_BETA_N)
    if args.output is not None:
        check_copy_path(args.scene, args.output)
    scene = load_scene(args.scene)
    spp, seed = sampling(scene, args.spp, args.seed)
    width, height = scene.camera.resolution
    total = len(sigma_a) * len(beta_n)
    with progress_bar(total=total, unit="render", desc=f"{args.scene.name} {width}x{height} {spp} spp") as progress:
        result = calibrate(scene, sigma_a, beta_n, spp=spp, seed=seed, threads=args.threads, progress=progress)
    print(
        f"grid: sigma_a {' '.join(f'{s:g}' for s in sigma_a)} x beta_n {' '.join(f'{b:g}' for b in beta_n)}; "
        f"measured over {result.pixels} fully covered pixels"
    )
    print(result.table())
    print(result.summary())
    print(inversion_toml(result.coefficients), end="")
    if args.output is not None:
        print(f"wrote {write_calibrated_scene(args.scene, args.output, result.coefficients)}")


@contextlib.contextmanager
def progress_bar(**tqdm_args):
    """A tqdm bar as the library's progress(done, total) callback (the total may grow as work is found)."""
    from tqdm import tqdm

    with tqdm(**tqdm_args) as bar:

        def progress(done, total):
            bar.total = total
            bar.update(done - bar.n)

        yield progress


SUBCOMMANDS = (add_plot_bsdf, add_render, add_gradcheck, add_export, add_calibrate)


def build_parser(extra=()) -> argparse.ArgumentParser:
    """The parser of the renderer's subcommands, plus `extra` ones (add_* functions) from packages built on it."""
    parser = argparse.ArgumentParser(prog=PROG, description="Hair and fur appearance (the Chiang et al. BSDF) in Warp.")
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an unexpected error")
    parser.add_argument(
        "--verbose",
        action="store_true",
        help="show Warp's own messages: its banner, each module it compiles or loads, its CUDA driver probe",
    )
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in SUBCOMMANDS + tuple(extra):
        add(subparsers)
    return parser


def exit_on_interrupt(run) -> None:
    """Run `run()` (a script's main) and exit: on Ctrl-C with one line and status 130, as the command does; Warp's
    own messages left out as the command leaves them out."""
    try:
        with wp.ScopedLogLevel(wp.LOG_WARNING), interrupts_delivered():  # Warp logs every module load at INFO
            init_warp()
            run()
    except KeyboardInterrupt:
        print(f"{sys.argv[0]}: interrupted", file=sys.stderr)
        sys.exit(130)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None, extra=()) -> int:
    """Run a subcommand. The installed `warp-hair` is optimize.cli.main, which adds the fitting subcommands
    (fit, targets) through `extra`: the renderer does not depend on the optimiser."""
    args = build_parser(extra).parse_args(argv)
    # Warp logs every module load at INFO: the command shows its warnings and errors only (unless --verbose), and
    # leaves the level as it was when it returns (main may run inside a host program).
    level = wp.LOG_INFO if args.verbose else wp.LOG_WARNING
    with warnings.catch_warnings(), wp.ScopedLogLevel(level), interrupts_delivered():
        # Users of the command see the library's warnings as messages, not as source locations.
        warnings.showwarning = _show_warning
        try:
            init_warp(args.verbose)
            # A command's own verdict (e.g. `targets check` on a bad target) may set the exit status.
            status = args.run(args)
        except KeyboardInterrupt:
            print(f"{PROG}: interrupted", file=sys.stderr)
            return 130
        # The library's errors: bad input (ValueError, FiberDataError) and files (OSError).
        except (ValueError, OSError) as error:
            print(f"{PROG}: error: {error}", file=sys.stderr)
            return 2
        except MemoryError:
            print(f"{PROG}: error: out of memory; lower the resolution, spp or fiber count", file=sys.stderr)
            return 2
        except Exception as error:
            if args.debug:
                traceback.print_exc()
            print(
                f"{PROG}: internal error: {type(error).__name__}: {error}\n"
                f"{PROG}: this is a bug in warp-hair; please report it on the project's issue tracker with the "
                "command line" + ("" if args.debug else ", and the traceback that --debug prints"),
                file=sys.stderr,
            )
            return 1
    return int(status or 0)


if __name__ == "__main__":
    sys.exit(main())

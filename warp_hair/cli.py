"""The `warp-hair` command line.

Each subcommand is an `add_*` function that declares its arguments and a function that runs it; the work
itself lives in the library. Bad input (a control out of range, an unwritable path) ends with
`warp-hair: error: <message>` on stderr and exit status 2, as argparse does for malformed arguments.

    warp-hair plot-bsdf -o lobes.png [hair controls] [--theta-o DEG ...] [--h H]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from .params import HairParams

PROG = "warp-hair"
DEFAULT_ALBEDO = (0.6, 0.4, 0.2)


def add_hair_controls(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "hair controls",
        "Colour: one of --albedo, --sigma-a, or --eumelanin/--pheomelanin (default --albedo 0.6 0.4 0.2).",
    )
    add = group.add_argument
    add("--albedo", nargs="+", type=float, metavar="C",
        help="multiple-scattering albedo in (0, 1]: one value (grey) or three (R G B)")
    add("--sigma-a", nargs="+", type=float, metavar="S",
        help="absorption per unit fiber radius, >= 0: one value (grey) or three (R G B)")
    add("--eumelanin", type=float, metavar="X", help="eumelanin concentration >= 0 (blonde 0.3, brown 1.3, black 8)")
    add("--pheomelanin", type=float, metavar="Y", help="pheomelanin (red-yellow pigment) concentration >= 0")
    add("--beta-m", type=float, default=0.3, metavar="B", help="longitudinal roughness in [0, 1] (default 0.3)")
    add("--beta-n", type=float, default=0.3, metavar="B", help="azimuthal roughness in [0, 1] (default 0.3)")
    add("--alpha", type=float, default=2.0, metavar="DEG", help="cuticle tilt in degrees, in [-30, 30] (default 2)")
    add("--eta", type=float, default=1.55, metavar="E", help="index of refraction, > 1 (default 1.55)")
    add("--r-roughness-scale", type=float, default=1.0, metavar="K",
        help="factor on the primary reflection's longitudinal roughness, > 0 (default 1)")


def hair_params(args: argparse.Namespace) -> HairParams:
    colour = dict(albedo=args.albedo, sigma_a=args.sigma_a, eumelanin=args.eumelanin, pheomelanin=args.pheomelanin)
    if all(value is None for value in colour.values()):
        colour["albedo"] = DEFAULT_ALBEDO
    return HairParams(
        **colour,
        beta_m=args.beta_m,
        beta_n=args.beta_n,
        alpha=args.alpha,
        eta=args.eta,
        r_roughness_scale=args.r_roughness_scale,
    )


def add_plot_bsdf(subparsers) -> None:
    parser = subparsers.add_parser(
        "plot-bsdf",
        help="plot the lobes of a hair material to a PNG",
        description="Plot the azimuthal (top row) and longitudinal (bottom row) lobes of a hair material, "
        "one column per viewing angle, for checking a material by eye.",
    )
    parser.add_argument("-o", "--output", required=True, type=Path, metavar="PNG", help="the PNG file to write")
    add_hair_controls(parser)
    parser.add_argument("--theta-o", nargs="+", type=float, default=[0.0, 30.0, 60.0], metavar="DEG",
                        help="viewing angles from the fiber's normal plane, in (-90, 90) (default 0 30 60)")
    parser.add_argument("--h", type=float, metavar="H",
                        help="fiber offset in [-1, 1] (default: averaged over h, the far-field look)")
    parser.set_defaults(run=plot_bsdf)


def plot_bsdf(args: argparse.Namespace) -> None:
    from .plot import plot_lobes  # matplotlib is needed by this command only

    print(plot_lobes(hair_params(args), args.output, theta_o_deg=args.theta_o, h=args.h))


SUBCOMMANDS = (add_plot_bsdf,)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description="Hair and fur appearance (the Chiang et al. BSDF) in Warp.")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in SUBCOMMANDS:
        add(subparsers)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"{PROG}: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with warnings.catch_warnings():
        # Users of the command see the library's warnings as messages, not as source locations.
        warnings.showwarning = _show_warning
        try:
            args.run(args)
        except (ValueError, OSError) as error:
            print(f"{PROG}: error: {error}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())

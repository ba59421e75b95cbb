"""The arguments `warp-hair targets photo` passes to `make_photo_target`, parsed by the command's own parser, so
that tests give only the options they are about and the rest take the command's defaults."""

from __future__ import annotations


def photo_args(*options: str):
    from optimize.cli import add_batch, add_fit, add_targets
    from warp_hair.cli import build_parser

    return build_parser((add_fit, add_targets, add_batch)).parse_args(["targets", "photo", "unused", *options])

"""`--sandbox DIR`, the CLI's one switch between trusted and confined input (pipeline/paths.py).

A file named on the command line is the user's own: it reads the files around it as usdview,
Blender and f3d let it (absolute paths and `..` included; never URLs). `--sandbox DIR` confines
every file it reads to DIR, as the service always confines uploads."""
from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.paths import UNCONFINED


def add_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--sandbox", type=Path, default=None, metavar="DIR",
                        help="confine every file an asset reads to DIR, which must hold it (for "
                             "untrusted files; default: local files read their neighbours freely)")


def root(args: argparse.Namespace) -> Path:
    return args.sandbox if args.sandbox is not None else UNCONFINED

"""`asset-preview` command line: one entry point, a module per subcommand.

Each subcommand module exposes `configure(parser)` and `run(args) -> int` and keeps heavy
imports (pxr, moderngl, embree) inside `run`, so `--help` stays fast.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Collection

COMMANDS = {
    "inspect": ("cli.inspect", "print what an asset holds (meshes, materials, bounds)"),
    "bake": ("cli.bake", "bake assets and environments into the cache (= asset-bake)"),
    "render": ("cli.render", "render a thumbnail of an asset"),
    "serve": ("cli.serve", "run the thumbnail HTTP service"),
    "bench": ("cli.bench", "benchmarks: our figures beside peers measured in the same run"),
}


def add_commands(parser: argparse.ArgumentParser, table: dict[str, tuple[str, str]],
                 dest: str, run_attr: str, only: Collection[str] | None = None) -> None:
    """One subcommand per (module, help) entry; the module's `run` lands in `args.<run_attr>`.
    With `only`, the other entries are listed (for --help) but their modules not imported."""
    sub = parser.add_subparsers(dest=dest, required=True, metavar=dest.upper())
    for name, (module, help_text) in table.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if only is not None and name not in only:
            continue
        mod = importlib.import_module(module)
        mod.configure(p)
        p.set_defaults(**{run_attr: mod.run})


# Commands whose numeric work runs in GL, Embree and numba kernels, never in large BLAS products:
# their process keeps OpenBLAS to one thread. Its pool, started as numpy loads, spun a second
# core for ~40 ms of CPU of every cold render (bench/RESULTS.md). Set before numpy is imported,
# and only where unset (the user's value stands); `bench` and `serve` are left as they are, so
# a peer's process (Storm) inherits nothing of ours.
ONE_BLAS_THREAD = frozenset({"render", "bake", "inspect"})


def _command(words: list[str]) -> str | None:
    """The subcommand `words` name (the top-level options take no values: the first other word)."""
    return next((w for w in words if not w.startswith("-")), None)


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The parser for `argv`: only the command it names is configured, so a cold `render`
    does not import the service's settings and every benchmark to build options it never
    parses (the top-level options take no values: the first other word is the command)."""
    parser = argparse.ArgumentParser(prog="asset-preview", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    command = _command(sys.argv[1:] if argv is None else argv)
    add_commands(parser, COMMANDS, "command", "_run", only=[command] if command else [])
    return parser


def cli_message(exc) -> str:
    """The error as a command line says it: a reference refused for leaving the root names the
    flag that set it (the service says the same of the upload in its own words)."""
    from core.errors import UnsafeReference
    text = str(exc)
    if isinstance(exc, UnsafeReference) and ("outside the root" in text or "leaves the root" in text):
        text += " (the folder of --sandbox DIR: widen it, or leave it out for a trusted file)"
    return text


def run_guarded(run, args) -> int:
    """Run a command; an AssetError becomes `error: FILE: REASON` and exit status 3."""
    from core.errors import AssetError
    try:
        return int(run(args) or 0)
    except AssetError as exc:
        print(f"error: {cli_message(exc)}", file=sys.stderr)
        return 3
    except BrokenPipeError:
        # the reader went away (`... | head`): not an error; keep Python from complaining at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


def main(argv: list[str] | None = None) -> int:
    if _command(sys.argv[1:] if argv is None else argv) in ONE_BLAS_THREAD and "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args = build_parser(argv).parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    return run_guarded(args._run, args)


if __name__ == "__main__":
    sys.exit(main())

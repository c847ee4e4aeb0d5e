"""Bake assets and environments into the content-addressed cache (`asset-bake` = `asset-preview bake`).

One result line per input on stdout (`baked`, `cached`, or `failed: REASON`), or one JSON
object per line with --json; a progress bar on stderr when it is a terminal; a summary on
stderr. Exit status 0 when everything baked, 3 when anything failed (the rest is still baked).
--workers N bakes in N spawned processes (not forked: EGL and Embree state do not survive fork);
--executor ray runs the same jobs as Ray tasks on a cluster (pipeline/executors.py).
Local files read their neighbours freely (a library's shared parts anywhere); --sandbox DIR
confines every asset to DIR (cli/sandbox.py).
--thumbnails DIR also renders every baked asset with the render options, where it was baked
(this process, a pool process or a Ray task: one GL context each, kept across assets),
through the cache into DIR, resumable, with DIR/manifest.json (cli/thumbnails.py).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

from cli import sandbox
from pipeline.bake import bake_one

log = logging.getLogger(__name__)

EXIT_FAILED = 3


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("paths", nargs="*", metavar="PATH",
                        help="asset files, or folders searched recursively for supported files")
    parser.add_argument("--cache", metavar="DIR", default=None,
                        help="cache folder (default: $ASSET_PREVIEW_CACHE, else ./.cache)")
    parser.add_argument("--env", action="append", default=[], metavar="NAME|FILE",
                        help="also bake this environment: a bundled name or a panorama file "
                             "(repeatable)")
    parser.add_argument("--prefilter", choices=("ggx", "paper"), default="ggx",
                        help="environment prefiltering: GGX importance sampling (default) or the "
                             "paper's plain Gaussian mip chain")
    parser.add_argument("--face-size", type=int, default=None, metavar="PX",
                        help="environment cube face size, a power of two (default "
                             "$ASSET_PREVIEW_FACE_SIZE, else 256)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="bake in N processes (default $ASSET_PREVIEW_BAKE_WORKERS, else 1: in "
                             "this process)")
    parser.add_argument("--executor", choices=("local", "ray"), default=None,
                        help="local processes (default), or Ray tasks on a cluster (--ray-address; "
                             "without one, a new local Ray with --workers CPUs, default all)")
    parser.add_argument("--ray-address", default=None, metavar="auto|HOST:PORT|ray://HOST:PORT",
                        help="Ray cluster to join (default $RAY_ADDRESS, else a new local one)")
    parser.add_argument("--max-size", default=None, metavar="SIZE",
                        help="cap the cache at SIZE (e.g. 2G), evicting least recently used "
                             "entries (default: $ASSET_PREVIEW_CACHE_MAX_BYTES, else no cap)")
    sandbox.add_argument(parser)
    parser.add_argument("--force", action="store_true", help="bake again even when cached")
    parser.add_argument("--json", action="store_true", help="one JSON object per input")
    parser.add_argument("--thumbnails", metavar="DIR", default=None,
                        help="also render each baked asset into DIR (render options below; "
                             "DIR/manifest.json; a re-run renders only what changed)")
    parser.add_argument("--thumbnail-format", default="png", metavar="png|jpg|webp|gif",
                        help="thumbnail file format (webp or gif for --turntable)")
    parser.add_argument("--quality", type=int, default=None, help="JPEG / WebP thumbnail quality")
    from core.options import add_arguments
    add_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from pipeline.cache import parse_size
    from pipeline.limits import pipeline_settings

    defaults = pipeline_settings()
    for name in ("workers", "face_size", "executor"):
        if getattr(args, name) is None:
            setattr(args, name, getattr(defaults, "bake_workers" if name == "workers" else name))
    if not args.paths and not args.env:
        print("error: nothing to bake: give asset paths and/or --env", file=sys.stderr)
        return 2
    if args.workers < 1:
        print("error: --workers must be at least 1", file=sys.stderr)
        return 2
    try:
        max_bytes = parse_size(args.max_size)
    except ValueError as exc:
        print(f"error: --max-size: {exc}", file=sys.stderr)
        return 2
    thumbs = None
    if args.thumbnails:
        from cli.thumbnails import Thumbnails, check_format
        from core.options import describe_error, from_arguments
        from renderer.raster.render import validate_options
        try:
            options = from_arguments(args)
            validate_options(options)  # refused before any bake
        except ValueError as exc:  # pydantic's ValidationError is one (core.schema)
            print(f"error: {describe_error(exc)}", file=sys.stderr)
            return 2
        if why := check_format(args.thumbnail_format, options):
            print(f"error: {why}", file=sys.stderr)
            return 2
        thumbs = Thumbnails(Path(args.thumbnails), str(args.cache) if args.cache else None, options,
                            args.thumbnail_format, args.env[0] if args.env else None, args.quality)
    if args.executor == "ray":
        from pipeline.executors import ExecutorUnavailable, connect
        try:
            connect(args.ray_address, num_cpus=args.workers if args.workers > 1 else None)
        except ExecutorUnavailable as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    cache = str(args.cache) if args.cache else None
    jobs, failures, folders = _collect(args.paths, cache)
    roots = {src: str(sandbox.root(args)) for _, src in jobs}  # as text: it travels to Ray tasks
    library = tuple(folders)  # found under a folder argument: one may be a part of another
    from pipeline.library import usd_parts
    parts = usd_parts([Path(p) for p in library])
    skipped = [{"kind": "asset", "path": src, "status": "skipped", "seconds": 0.0,
                "note": f"a part of {parts[src]} (it references, sublayers or payloads it)"}
               for _, src in jobs if src in parts]
    jobs = [j for j in jobs if j[1] not in parts]
    jobs += [("environment", src) for src in args.env]
    common = {"cache": cache, "max_bytes": max_bytes, "force": args.force,
              "face_size": args.face_size, "prefilter": args.prefilter, "roots": roots,
              "library": library}
    report = _Report(len(jobs) + len(failures) + len(skipped), args.json, thumbs, folders)
    for result in skipped:
        report.add(result)
    for result in failures:
        report.add(result)
    start = time.perf_counter()
    # With thumbnails, each job renders its asset right after baking it, in the same process.
    then = thumbs.renderer if thumbs is not None else None
    hint = thumbs.known if thumbs is not None else None
    try:
        if args.executor == "ray":
            from pipeline.executors import run_ray
            run_ray(jobs, common, report, then=then, hint=hint)
        elif args.workers == 1 or len(jobs) <= 1:
            for kind, source in jobs:  # thumbnails: Report.add renders them in this process
                report.add(bake_one(kind, source, **common))
        else:
            _run_pool(jobs, common, args.workers, report, then, hint)
    except KeyboardInterrupt:
        report.close()
        print("interrupted", file=sys.stderr)
        return 130
    report.close()
    counts = report.counts
    thumbed = ""
    if thumbs is not None:
        thumbed = (f"; thumbnails: {report.thumb_counts['rendered']} rendered, "
                   f"{report.thumb_counts['cached']} from the cache, "
                   f"{report.thumb_counts['kept']} kept, {report.thumb_counts['failed']} failed")
    print(f"{counts['baked']} baked, {counts['cached']} cached, {counts['skipped']} skipped, "
          f"{counts['failed']} failed{thumbed} "
          f"in {time.perf_counter() - start:.2f} s", file=sys.stderr)
    return EXIT_FAILED if counts["failed"] or report.thumb_counts["failed"] else 0


def main(argv: list[str] | None = None) -> int:
    """The `asset-bake` console script."""
    parser = argparse.ArgumentParser(prog="asset-bake", description=__doc__.split("\n\n")[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress to stderr")
    configure(parser)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return run(args)
    except BrokenPipeError:  # `asset-bake ... | head`: stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


def _collect(paths: list[str], cache: str | None):
    """Asset jobs for the given files and folders, failures for paths that are neither, and
    the folder argument each asset was found under (its thumbnail is named relative to it)."""
    from pipeline.cache import default_cache_dir
    from pipeline.ingest import READERS

    cache_root = Path(cache or default_cache_dir()).resolve()
    jobs, failures, seen, folders = [], [], set(), {}

    def add(path: Path, folder: Path | None = None) -> None:
        key = path.resolve()
        if key not in seen:
            seen.add(key)
            jobs.append(("asset", str(path)))
            if folder is not None:
                folders[str(path)] = str(folder)

    for raw in paths:
        path = Path(raw)
        if path.is_dir():
            found = 0
            for folder, dirs, files in os.walk(path):
                # hidden folders (.git, .cache) and the cache itself are never assets
                dirs[:] = sorted(d for d in dirs if not d.startswith(".")
                                 and Path(folder, d).resolve() != cache_root)
                for name in sorted(files):
                    if Path(name).suffix.lower() in READERS and not name.startswith("."):
                        add(Path(folder, name), path)
                        found += 1
            if not found:
                failures.append({"kind": "asset", "path": raw, "status": "failed",
                                 "error": f"{raw}: no supported asset files in this folder "
                                          f"({', '.join(sorted(READERS))})", "seconds": 0.0})
        else:
            add(path)  # a missing or unsupported file fails in bake_one, with the reason
    return jobs, failures, folders


def _run_pool(jobs, common: dict, workers: int, report: "_Report", then=None, hint=None) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from pipeline.executors import run_job

    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx) as pool:
        futures = {pool.submit(run_job, kind, source, common, then, hint(source) if hint else None):
                   (kind, source) for kind, source in jobs}
        try:
            for future in as_completed(futures):
                kind, source = futures[future]
                try:
                    report.add(future.result())
                except BrokenProcessPool:
                    report.add({"kind": kind, "path": source, "status": "failed", "seconds": 0.0,
                                "error": f"{source}: a bake worker process died (crash or out of memory)"})
        except KeyboardInterrupt:
            pool.shutdown(wait=False, cancel_futures=True)
            raise


class _Report:
    """Result lines on stdout, and a tqdm progress bar on stderr when it is a terminal."""

    def __init__(self, total: int, as_json: bool, thumbs=None, folders: dict | None = None):
        from tqdm import tqdm

        self.as_json, self.thumbs, self.folders = as_json, thumbs, folders or {}
        self.thumb_counts = {"rendered": 0, "cached": 0, "kept": 0, "failed": 0}
        self.out = sys.stdout  # held: the Ray executor moves other writers' stdout to stderr
        self.counts = {"baked": 0, "cached": 0, "skipped": 0, "failed": 0}
        self.bar = tqdm(total=total, file=sys.stderr, unit="file", leave=False,
                        disable=not (sys.stderr.isatty() and total > 1))

    def add(self, result: dict) -> None:
        """One result (as it arrives from any executor); with --thumbnails, its thumbnail
        (rendered where it was baked; here when it was baked here) put into DIR."""
        self.counts[result["status"]] += 1
        if self.thumbs is not None and result["kind"] == "asset" and result["status"] != "skipped":
            entry = self.thumbs.add(result, self.folders.get(result["path"]))
            self.thumb_counts[entry["status"]] += 1
            result = {**result, "thumbnail": {k: entry[k] for k in ("status", "files") if k in entry}}
            if entry["status"] == "failed" and result["status"] != "failed":
                result["thumbnail"]["error"] = entry["error"]
        if self.as_json:
            line = json.dumps(result)
        elif result["status"] == "failed":
            line = f"failed: {result['error']}"
        elif result["status"] == "skipped":
            line = f"skipped {result['path']}  ({result['note']})"
        else:
            line = (f"{result['status']:<7}{result['path']}  (key {result['key'][:12]}, "
                    f"{result['seconds']:.2f} s)")
            if thumb := result.get("thumbnail"):
                line += f"  thumbnail {thumb['status']}" + (f": {thumb['error']}" if "error" in thumb else "")
        self.bar.write(line, file=self.out)  # above the bar, which redraws below it
        self.out.flush()
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()
        if self.thumbs is not None:
            self.thumbs.flush()


if __name__ == "__main__":
    sys.exit(main())

"""`asset-preview serve`: run the thumbnail HTTP service with uvicorn."""
from __future__ import annotations

import argparse


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="port (default 8000)")
    parser.add_argument("--cache", help="cache folder (default $ASSET_PREVIEW_CACHE or ./.cache)")
    parser.add_argument("--workers", type=int, help="render worker processes (default one per core)")
    parser.add_argument("--executor", choices=["local", "ray"],
                        help="render in local worker processes (default) or Ray actors")
    parser.add_argument("--ray-address", help="Ray cluster to join: auto, HOST:PORT or ray://HOST:PORT "
                                              "(default $RAY_ADDRESS, else a new local one)")
    parser.add_argument("--ray-gpus", type=float, help="GPU share per render actor (default 0)")
    parser.add_argument("--api-key", help="require `Authorization: Bearer KEY` for POST and DELETE "
                                          "(default $ASSET_PREVIEW_API_KEY; none)")
    parser.add_argument("--max-upload-bytes", type=int, help="largest request body (413 beyond)")
    parser.add_argument("--max-thumbnail-size", type=int, help="largest width/height (422 beyond)")
    parser.add_argument("--max-queue", type=int, help="renders waiting or running (503 beyond)")
    parser.add_argument("--render-seconds", type=float, help="deadline of one render")
    parser.add_argument("--bake-seconds", type=float, help="deadline of one bake")
    parser.add_argument("--no-seed", dest="seed", action="store_false", default=None,
                        help="do not seed the sample assets into an empty store")
    parser.add_argument("--access-log", action="store_true", help="log every request (off: /metrics counts them)")
    parser.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])


def run(args: argparse.Namespace) -> int:
    import logging

    import uvicorn

    from service.app import create_app
    from service.settings import Settings

    logging.getLogger().setLevel(args.log_level.upper())
    settings = Settings.from_env(
        cache=args.cache, workers=args.workers, api_key=args.api_key, executor=args.executor,
        ray_address=args.ray_address, ray_gpus=args.ray_gpus,
        max_upload_bytes=args.max_upload_bytes, max_thumbnail_size=args.max_thumbnail_size,
        max_queue=args.max_queue, render_seconds=args.render_seconds, bake_seconds=args.bake_seconds,
        seed=args.seed)
    config = uvicorn.Config(create_app(settings), host=args.host, port=args.port,
                            log_level=args.log_level, access_log=args.access_log, timeout_graceful_shutdown=10)
    uvicorn.Server(config).run()
    return 0

"""`asset-preview serve`: run the thumbnail HTTP service with uvicorn.

Every service setting (service/settings.py) is a flag `--name-with-dashes`, declared there once;
a flag left out falls back to ASSET_PREVIEW_NAME, then to the default.
"""
from __future__ import annotations

import argparse
import ipaddress
import socket
import sys

from core.schema import declared
from service.settings import Settings

ALIASES = {"render_workers": ["--workers"]}


def configure(parser: argparse.ArgumentParser) -> None:
    for name, field in declared(Settings).items():
        flags = ["--" + name.replace("_", "-"), *ALIASES.get(name, [])]
        env = "ASSET_PREVIEW_" + name.upper()
        help_text = f"{field.description} (${env}; default {field.default!s})"
        if field.annotation is bool:
            parser.add_argument(*flags, dest=name, action=argparse.BooleanOptionalAction, default=None,
                                help=help_text)
        else:
            kind = {int: int, float: float}.get(field.annotation, str)  # type: ignore[arg-type]
            parser.add_argument(*flags, dest=name, type=kind, default=None, help=help_text)
    parser.add_argument("--access-log", action="store_true", help="log every request (off: /metrics counts them)")
    parser.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])


def settings_table(model=Settings, flags: bool = True) -> str:
    """README's table of settings, from the one declaration."""
    rows = ["| flag | variable | default | meaning |" if flags else "| variable | default | meaning |",
            "|---|---|---|---|" if flags else "|---|---|---|"]
    for name, field in declared(model).items():
        flag = f"`--{name.replace('_', '-')}` | " if flags else ""
        rows.append(f"| {flag}`ASSET_PREVIEW_{name.upper()}` | `{field.default!s}` | {field.description or ''} |")
    return "\n".join(rows)


def is_loopback(host: str) -> bool:
    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except socket.gaierror:
        return False
    return all(ipaddress.ip_address(str(a).split("%")[0]).is_loopback for a in addresses)


def run(args: argparse.Namespace) -> int:
    import logging

    import uvicorn

    from service.http.app import create_app

    logging.getLogger().setLevel(args.log_level.upper())
    from pydantic import ValidationError
    try:
        settings = Settings.from_env(**{name: getattr(args, name) for name in declared(Settings)})
    except ValidationError as exc:  # a bad flag or ASSET_PREVIEW_* value: say which, no traceback
        for e in exc.errors():
            name = str(e["loc"][0]) if e["loc"] else "?"
            print(f"error: --{name.replace('_', '-')} / ASSET_PREVIEW_{name.upper()}: {e['msg']}",
                  file=sys.stderr)
        return 2
    if not settings.api_keys and not settings.insecure_no_auth and not is_loopback(settings.host):
        print(f"error: refusing to serve {settings.host} without an API key: anyone who can reach it "
              "could upload and delete. Set --api-key (or ASSET_PREVIEW_API_KEY), or pass "
              "--insecure-no-auth to serve it open.", file=sys.stderr)
        return 2
    config = uvicorn.Config(create_app(settings), host=settings.host, port=settings.port,
                            log_level=args.log_level, access_log=args.access_log, timeout_graceful_shutdown=10)
    uvicorn.Server(config).run()
    return 0


if __name__ == "__main__":  # README's settings tables: python -m cli.serve
    from core.config import RendererSettings
    from pipeline.limits import Limits, PipelineSettings
    print(settings_table(), settings_table(Limits, False), settings_table(PipelineSettings, False),
          settings_table(RendererSettings, False), sep="\n\n")

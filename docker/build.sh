#!/bin/sh
# Build the service image (asset-preview:latest): with docker when its daemon answers, else podman
# with docker/containers.conf (runc, cgroupfs, no default ulimits: hosts without systemd).
#   docker/build.sh                      FROM python:3.11-slim (pulled)
#   BASE=debootstrap docker/build.sh     FROM a Debian 12 minbase made here (no registry needed)
#   SMOKE=1 docker/build.sh              then run it: /readyz, an upload, a PNG thumbnail
# The debootstrapped root is kept in $ROOTFS (default .cache/base-rootfs) and imported once.
set -eu
cd "$(dirname "$0")/.."
TAG=${TAG:-asset-preview:latest}
BASE=${BASE:-python:3.11-slim}
ROOTFS=${ROOTFS:-$PWD/.cache/base-rootfs}
export CONTAINERS_CONF="${CONTAINERS_CONF:-$PWD/docker/containers.conf}"
if command -v docker >/dev/null && docker info >/dev/null 2>&1; then
  ENGINE=docker; RUNTIME=""
else
  ENGINE=podman; RUNTIME="--runtime runc"
fi

if [ "$BASE" = debootstrap ]; then
  BASE=localhost/asset-preview-base:bookworm
  if ! $ENGINE image inspect "$BASE" >/dev/null 2>&1; then
    if [ ! -x "$ROOTFS/usr/bin/python3" ]; then
      echo "== debootstrap Debian 12 minbase (python3, python3-venv) into $ROOTFS"
      debootstrap --variant=minbase --include=python3,python3-venv bookworm "$ROOTFS" \
        "${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
    fi
    echo "== $ENGINE import $BASE"
    tar -C "$ROOTFS" -c . | $ENGINE import - "$BASE"
  fi
fi

# The host's pip settings (a local wheel folder or file:// index, a proxy's CA bundle) pass into
# the build, their folders and files mounted read-only at the same paths, where podman allows it.
set -- --build-arg "BASE=$BASE" --network host -f docker/Dockerfile -t "$TAG"
if [ "$ENGINE" = podman ]; then
  for var in PIP_FIND_LINKS PIP_EXTRA_INDEX_URL PIP_INDEX_URL PIP_CERT; do
    val=$(eval echo "\${$var:-}")
    [ -n "$val" ] || continue
    set -- "$@" --build-arg "$var=$val"
    for path in $(echo "$val" | sed 's#file://##g'); do
      case "$path" in */simple) path=$(dirname "$path");; esac  # the index's files sit beside it
      [ -e "$path" ] && set -- "$@" --volume "$path:$path:ro"
    done
  done
fi
echo "== $ENGINE build $TAG from $BASE"
$ENGINE build "$@" .

[ "${SMOKE:-0}" = 1 ] || exit 0
PORT=${PORT:-18080}
NAME=asset-preview-smoke
$ENGINE rm -f -v "$NAME" >/dev/null 2>&1 || true
echo "== $ENGINE run $TAG on 127.0.0.1:$PORT"
# shellcheck disable=SC2086
$ENGINE run $RUNTIME -d --name "$NAME" -p "127.0.0.1:$PORT:8000" \
  -e ASSET_PREVIEW_INSECURE_NO_AUTH=true -e ASSET_PREVIEW_RENDER_WORKERS=1 "$TAG" >/dev/null
trap '$ENGINE rm -f -v "$NAME" >/dev/null 2>&1 || true' EXIT  # -v: its /data volume too
python3 docker/smoke.py "http://127.0.0.1:$PORT" tests/assets/gltf/Duck.glb "${SMOKE_OUT:-.cache/smoke-thumbnail.png}"

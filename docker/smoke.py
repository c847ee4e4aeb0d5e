"""Check a running image from outside it: /readyz, an upload, a PNG thumbnail (stdlib only).
    python3 docker/smoke.py http://127.0.0.1:18080 tests/assets/gltf/Duck.glb out.png"""
import json
import sys
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path


def main(base: str, asset: str, out: str) -> int:
    end = time.monotonic() + 300
    while True:
        try:
            with urllib.request.urlopen(f"{base}/readyz", timeout=5) as r:
                if r.status == 200:
                    break
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        if time.monotonic() > end:
            print(f"error: {base}/readyz did not answer 200 in 300 s", file=sys.stderr)
            return 1
        time.sleep(1)
    print("readyz: 200")
    data = Path(asset).read_bytes()
    boundary = uuid.uuid4().hex
    body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; filename=\"{Path(asset).name}\"\r\n"
            "Content-Type: application/octet-stream\r\n\r\n").encode() + data + f"\r\n--{boundary}--\r\n".encode()
    req = urllib.request.Request(f"{base}/assets", data=body, method="POST",
                                 headers={"Content-Type": f"multipart/form-data; boundary={boundary}"})
    with urllib.request.urlopen(req, timeout=300) as r:
        rec = json.load(r)
    print(f"upload: {r.status} id {rec['id']} status {rec.get('status')}")
    with urllib.request.urlopen(f"{base}/assets/{rec['id']}/thumbnail?size=256", timeout=300) as r:
        png = r.read()
        kind = r.headers.get("content-type")
    if not png.startswith(b"\x89PNG\r\n\x1a\n"):
        print(f"error: thumbnail is not a PNG ({kind}, {len(png)} bytes)", file=sys.stderr)
        return 1
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_bytes(png)
    print(f"thumbnail: {kind}, {len(png)} bytes -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:4]))

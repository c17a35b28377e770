"""``dlo bench --bombs``: how fast, and how cheaply, the service refuses decompression bombs.

A bomb is a small file that decodes to a huge image: :func:`blank_png` writes a valid
1-bit PNG of 30000x30000 zeros in about 110 KB, 900 megapixels (2.7 GB as BGR) once
decoded. A ``dlo serve`` process (HTTP only, on loopback) is sent it as the image (raw
body) and as the mask of a small image (multipart), one request at a time; the answers must
be 413, and the server's peak resident memory (``VmHWM``, Linux) is read before and after.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import os
import re
import statistics
import struct
import subprocess
import sys
import time
import zlib
from collections.abc import Iterator
from pathlib import Path

BOMB_SIDE = 30_000
DLO = [sys.executable, "-c", "from service.cli import main; main()"]
BOUNDARY = "dlo-bench-bomb"


def blank_png(width: int, height: int, bit_depth: int = 1) -> bytes:
    """A valid greyscale PNG of ``width`` x ``height`` zeros, made without any image.

    With the default 1-bit samples a 30000x30000 one is about 110 KB that decodes to 900
    megapixels (a decompression bomb); it is compressed a block of rows at a time, so
    making it takes well under a second and little memory.
    """

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    row = b"\0" * (1 + (width * bit_depth + 7) // 8)
    rows_per_block = max(1, 4_000_000 // len(row))
    compressor = zlib.compressobj(9)
    parts = []
    for start in range(0, height, rows_per_block):
        parts.append(compressor.compress(row * min(rows_per_block, height - start)))
    parts.append(compressor.flush())
    header = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", b"".join(parts))
        + chunk(b"IEND", b"")
    )


def run_bomb_bench(requests: int, as_json: bool) -> int:
    """Time ``requests`` refusals of each kind; print a table (or JSON); the exit status."""
    import cv2
    import numpy as np

    from service.bench.overhead import _free_port, _wait_until_ready

    bomb = blank_png(BOMB_SIDE, BOMB_SIDE)
    small = cv2.imencode(".png", np.zeros((360, 640, 3), np.uint8))[1].tobytes()
    kinds = {
        "image (raw body)": (bomb, "image/png"),
        "mask (multipart)": _multipart({"image": small, "mask": bomb}),
    }
    port = _free_port()
    rows = []
    with _dlo_serve(port) as process:
        _wait_until_ready(process, port, Path(os.devnull))
        before = peak_rss_mb(process.pid)
        connection = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        for name, (body, content_type) in kinds.items():
            times = []
            for _ in range(requests):
                started = time.perf_counter()
                connection.request(
                    "POST", "/v1/detect", body=body, headers={"Content-Type": content_type}
                )
                response = connection.getresponse()
                answer = response.read()
                times.append((time.perf_counter() - started) * 1000.0)
                if response.status != 413:
                    raise RuntimeError(f"{name}: answered {response.status}: {answer[:200]!r}")
            times.sort()
            rows.append(
                {
                    "upload": name,
                    "requests": requests,
                    "p50_ms": statistics.median(times),
                    "p99_ms": times[min(len(times) - 1, round(0.99 * (len(times) - 1)))],
                }
            )
        connection.close()
        after = peak_rss_mb(process.pid)
    results = {
        "bomb": f"{BOMB_SIDE}x{BOMB_SIDE} 1-bit PNG, {len(bomb)} bytes",
        "rows": rows,
        "server_peak_rss_mb": {"before": before, "after": after},
    }
    if as_json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"dlo bench --bombs: {results['bomb']}, sent to dlo serve on loopback; 413 each time")
    for row in rows:
        print(
            f"  {row['upload']:<18} {row['requests']} requests: p50 {row['p50_ms']:.2f} ms, "
            f"p99 {row['p99_ms']:.2f} ms"
        )
    print(f"  server peak resident memory: {before:.0f} MB before, {after:.0f} MB after")
    return 0


def _multipart(files: dict[str, bytes]) -> tuple[bytes, str]:
    body = b"".join(
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="{name}"; filename="{name}.png"'
        f"\r\nContent-Type: image/png\r\n\r\n".encode()
        + data
        + b"\r\n"
        for name, data in files.items()
    )
    return body + f"--{BOUNDARY}--\r\n".encode(), f"multipart/form-data; boundary={BOUNDARY}"


@contextlib.contextmanager
def _dlo_serve(port: int) -> Iterator[subprocess.Popen[bytes]]:
    environment = {
        **os.environ,
        "DLO_ZENOH": "false",
        "DLO_LOG_LEVEL": "warning",
        "DLO_HOST": "127.0.0.1",
        "DLO_PORT": str(port),
    }
    process = subprocess.Popen(
        [*DLO, "serve"], env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        yield process
    finally:
        process.terminate()
        process.wait(timeout=30)


def peak_rss_mb(pid: int) -> float:
    """The peak resident memory (``VmHWM``) of process ``pid`` in MiB; NaN off Linux."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return float("nan")
    found = re.search(r"VmHWM:\s+(\d+) kB", status)
    return int(found.group(1)) / 1024.0 if found else float("nan")

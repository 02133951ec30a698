"""Throughput and capacity of the live viewer server, on 127.0.0.1 only.

Measures, against a :class:`stiffness.viewer.server.LiveServer` holding a 1 MB scene:

* page requests per second (``GET /``) from ``--threads`` keep-alive-less clients for
  ``--seconds`` s, and the latency percentiles;
* connections held open at once before the server starts evicting the oldest;
* websocket pages connected at once (each sent the whole scene).

Every loop is bounded in count and time. Usage::

    python scripts/bench_viewer.py [--threads 8] [--seconds 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import threading
import time
import urllib.request

import numpy as np

from stiffness.viewer.deps import meshcat_modules
from stiffness.viewer.server import LOOPBACK, LiveServer


def page_rate(url: str, threads: int, seconds: float) -> dict:
    latencies: list[float] = []
    errors = [0]
    stop = time.monotonic() + seconds
    lock = threading.Lock()

    def client() -> None:
        while time.monotonic() < stop:
            start = time.monotonic()
            try:
                urllib.request.urlopen(url, timeout=2.0).read()
            except OSError:
                with lock:
                    errors[0] += 1
                continue
            with lock:
                latencies.append(time.monotonic() - start)

    workers = [threading.Thread(target=client) for _ in range(threads)]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    lat = np.array(latencies)
    return {"requests_per_s": len(lat) / seconds, "errors": errors[0],
            "latency_p50_ms": float(np.percentile(lat, 50) * 1e3),
            "latency_p99_ms": float(np.percentile(lat, 99) * 1e3),
            "latency_max_ms": float(lat.max() * 1e3)}


def connections_held(port: int, limit: int) -> int:
    """Connections opened until the oldest one is evicted (at most ``limit`` + 50 tried)."""
    held = []
    try:
        for _ in range(limit + 50):
            held.append(socket.create_connection((LOOPBACK, port), timeout=2.0))
        time.sleep(0.3)
        alive = 0
        for sock in held:
            sock.settimeout(0.01)
            try:
                alive += sock.recv(1) != b""
            except TimeoutError:
                alive += 1
            except OSError:
                pass
        return alive
    finally:
        for sock in held:
            sock.close()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    with LiveServer() as server:
        blob = meshcat_modules().msgpack.packb({"type": "set_object", "path": "/load",
                                         "object": {"data": os.urandom(2**20)}})
        server.request([b"set_object", b"/load", blob])
        port = int(server.web_url.rsplit(":", 1)[1].strip("/"))
        result = {"load_average": os.getloadavg(), "threads": args.threads,
                  **page_rate(server.web_url, args.threads, args.seconds),
                  "connections_held": connections_held(port, server.limits.max_connections),
                  "max_connections": server.limits.max_connections,
                  "max_websockets": server.limits.max_websockets}
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

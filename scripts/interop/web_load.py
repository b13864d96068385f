#!/usr/bin/env python3
"""Load on the web dashboard: N browsers' worth of live plant views (server-sent event
streams on /api/events), each in a thread of this separate process, held for --seconds,
while the gateway polls its loops. Standard library only.

Prints one JSON object: streams opened, events received (total, per stream, the fewest),
the gateway's polls per second before and during the load (from /api/devices), and
whether any stream failed.
"""

import argparse
import http.client
import json
import threading
import time
import urllib.parse
import urllib.request


def polls(base):
    plant = json.load(urllib.request.urlopen(base + "/api/devices"))
    return sum(d["polls"] for d in plant["devices"])


def stream(host, port, stop, counts, i, errors):
    try:
        c = http.client.HTTPConnection(host, port, timeout=30)
        c.request("GET", "/api/events", headers={"Accept": "text/event-stream"})
        r = c.getresponse()
        if r.status != 200:
            errors.append(f"stream {i}: HTTP {r.status}")
            return
        while not stop.is_set():
            line = r.fp.readline()
            if not line:
                errors.append(f"stream {i}: closed by the server")
                return
            if line.startswith(b"event: plant"):
                counts[i] += 1
        c.close()
    except Exception as e:  # a stream that fails is counted, not fatal
        errors.append(f"stream {i}: {e}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--streams", type=int, default=50)
    ap.add_argument("--seconds", type=float, default=60)
    a = ap.parse_args()
    base = a.url.rstrip("/")
    u = urllib.parse.urlparse(base)
    # The polling rate with no one watching.
    p0, t0 = polls(base), time.monotonic()
    time.sleep(a.seconds / 2)
    p1, t1 = polls(base), time.monotonic()
    stop = threading.Event()
    counts = [0] * a.streams
    errors = []
    threads = [threading.Thread(target=stream, args=(u.hostname, u.port, stop, counts, i, errors), daemon=True)
               for i in range(a.streams)]
    for t in threads:
        t.start()
    time.sleep(1)
    p2, t2 = polls(base), time.monotonic()
    time.sleep(a.seconds)
    p3, t3 = polls(base), time.monotonic()
    stop.set()
    print(json.dumps({
        "streams": a.streams,
        "seconds": a.seconds,
        "events": sum(counts),
        "events_per_stream_per_s": round(sum(counts) / a.streams / a.seconds, 2),
        "fewest_events": min(counts),
        "polls_per_s_idle": round((p1 - p0) / (t1 - t0), 2),
        "polls_per_s_loaded": round((p3 - p2) / (t3 - t2), 2),
        "errors": errors[:5],
    }))


if __name__ == "__main__":
    main()

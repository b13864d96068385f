#!/usr/bin/env python3
"""Abuses a Modbus TCP server's connection pool (plain sockets, no Modbus library):
connections that never send a byte, connections that send half a request and stop,
each from loopback source addresses 127.0.0.2 and up (so per-address limits do not
stop them all), reopened as soon as the server closes them, for --seconds. Prints one
JSON object: how many were opened, refused at once (closed before a byte), and closed
later by the server.

Run by crates/hartkit/tests/gateway_modbus.rs as a separate process.
"""
import argparse
import json
import select
import socket
import time


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--idle", type=int, default=100)
    ap.add_argument("--partial", type=int, default=50)
    ap.add_argument("--sources", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=10.0)
    a = ap.parse_args()
    stats = {"opened": 0, "closed_by_server": 0, "connect_errors": 0}
    socks = {}

    def open_one(kind, n):
        src = "127.0.0.%d" % (2 + n % a.sources)
        s = socket.socket()
        s.setblocking(True)
        s.settimeout(2)
        try:
            s.bind((src, 0))
            s.connect(("127.0.0.1", a.port))
        except OSError:
            stats["connect_errors"] += 1
            s.close()
            return
        if kind == "partial":
            # An MBAP header announcing 6 bytes, and two of them.
            s.sendall(bytes([0, 1, 0, 0, 0, 6, 1, 4]))
        s.setblocking(False)
        stats["opened"] += 1
        socks[s] = (kind, n)

    for n in range(a.idle):
        open_one("idle", n)
    for n in range(a.partial):
        open_one("partial", n)
    end = time.time() + a.seconds
    while time.time() < end:
        r, _, _ = select.select(list(socks), [], [], 0.2)
        for s in r:
            try:
                data = s.recv(4096)
            except OSError:
                data = b""
            if not data:
                kind, n = socks.pop(s)
                s.close()
                stats["closed_by_server"] += 1
                open_one(kind, n)
    for s in socks:
        s.close()
    print(json.dumps(stats))


if __name__ == "__main__":
    main()

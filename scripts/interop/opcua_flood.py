#!/usr/bin/env python3
"""Abuses an OPC UA server's port (asyncua's low-level client for the OPC UA parts, plain
sockets for the rest), from loopback source addresses 127.0.0.2 (--first-source) and up (so per-address
limits do not stop them all), each abuser reopened as soon as the server closes it, for
--seconds:

* idle: TCP connections that never send a byte;
* hello: a HEL, then silence (the ACK is read);
* opn: HEL and OPN (SecurityPolicy None), then silence: a secure channel never used;
* session: HEL, OPN, CreateSession never activated, then the socket closed and the
  next one opened at once (sessions pile up until they time out);
* oversized: HEL, then a chunk header announcing 2 GB and 64 KiB of it.

Prints one JSON object: connections opened per kind, closed by the server, refused
at once (closed before any answer), sessions created and refused.

Run by crates/hartkit/tests/gateway_opcua.rs as a separate process.
"""
import argparse
import asyncio
import json
import struct
import time

from asyncua import Client


def hello(url):
    u = url.encode()
    body = struct.pack("<IIIII", 0, 65535, 65535, 0, 0) + struct.pack("<i", len(u)) + u
    return b"HELF" + struct.pack("<I", 8 + len(body)) + body


class Flood:
    def __init__(self, a):
        self.a = a
        self.url = "opc.tcp://127.0.0.1:%d/" % a.port
        self.end = time.time() + a.seconds
        self.stats = {}

    def count(self, key, n=1):
        self.stats[key] = self.stats.get(key, 0) + n

    def src(self, n):
        return ("127.0.0.%d" % (self.a.first_source + n % self.a.sources), 0)

    async def raw(self, kind, n):
        """idle, hello, oversized: a plain socket."""
        while time.time() < self.end:
            try:
                r, w = await asyncio.wait_for(
                    asyncio.open_connection("127.0.0.1", self.a.port, local_addr=self.src(n)), 5
                )
            except (OSError, asyncio.TimeoutError):
                self.count("connect_errors")
                await asyncio.sleep(0.2)
                continue
            self.count(kind + "_opened")
            try:
                if kind in ("hello", "oversized"):
                    w.write(hello(self.url))
                    await w.drain()
                if kind == "oversized":
                    ack = await asyncio.wait_for(r.read(8), 5)
                    if ack[:3] == b"ACK":
                        w.write(b"MSGF" + struct.pack("<I", 0x7FFFFFF0) + bytes(65536))
                        await w.drain()
                # Wait for the server to close it (reading whatever it sends).
                while time.time() < self.end:
                    try:
                        data = await asyncio.wait_for(r.read(65536), 0.5)
                    except asyncio.TimeoutError:
                        continue
                    if not data:
                        self.count(kind + "_closed_by_server")
                        break
                    if data[:3] == b"ERR":
                        self.count(kind + "_err")
            except (OSError, asyncio.TimeoutError, asyncio.IncompleteReadError):
                self.count(kind + "_closed_by_server")
            finally:
                w.close()

    async def ua(self, kind, n):
        """opn, session: asyncua's client, stopped half way."""
        loop = asyncio.get_running_loop()
        while time.time() < self.end:
            c = Client(self.url, timeout=5)
            try:
                await asyncio.wait_for(
                    loop.create_connection(
                        c.uaclient._make_protocol, "127.0.0.1", self.a.port, local_addr=self.src(n)
                    ),
                    5,
                )
                self.count(kind + "_opened")
                await c.send_hello()
                await c.open_secure_channel()
                if kind == "session":
                    try:
                        await c.create_session()
                        self.count("sessions_created")
                    except Exception as e:
                        self.count("sessions_refused")
                        self.stats["session_refusal"] = type(e).__name__ + ": " + str(e)[:100]
                        await asyncio.sleep(0.5)
                    c.uaclient.disconnect_socket()
                    continue
                # A channel never used: wait for the server to close it.
                while time.time() < self.end:
                    await asyncio.sleep(0.25)
                    p = c.uaclient.protocol
                    if p is None or p.state == "closed" or p.transport is None or p.transport.is_closing():
                        self.count(kind + "_closed_by_server")
                        break
            except Exception as e:
                self.count(kind + "_failed")
                self.stats[kind + "_failure"] = type(e).__name__ + ": " + str(e)[:100]
                await asyncio.sleep(0.2)
            finally:
                try:
                    c.uaclient.disconnect_socket()
                except Exception:
                    pass

    async def run(self):
        tasks = []
        for kind in ("idle", "hello", "oversized"):
            for n in range(getattr(self.a, kind)):
                tasks.append(self.raw(kind, n))
        for kind in ("opn", "session"):
            for n in range(getattr(self.a, kind)):
                tasks.append(self.ua(kind, n))
        await asyncio.gather(*tasks)
        print(json.dumps(self.stats, sort_keys=True))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--idle", type=int, default=100)
    ap.add_argument("--hello", type=int, default=100)
    ap.add_argument("--opn", type=int, default=30)
    ap.add_argument("--session", type=int, default=10)
    ap.add_argument("--oversized", type=int, default=10)
    ap.add_argument("--sources", type=int, default=10)
    ap.add_argument("--first-source", type=int, default=2, help="127.0.0.N, the first")
    ap.add_argument("--seconds", type=float, default=15.0)
    a = ap.parse_args()
    import logging

    logging.disable(logging.CRITICAL)
    asyncio.run(Flood(a).run())


if __name__ == "__main__":
    main()

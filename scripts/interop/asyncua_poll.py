#!/usr/bin/env python3
"""A SCADA's poll over OPC UA (asyncua, LGPL): finds the first device's PV under
Objects/HART, reads it every --every seconds for --seconds (each read with a time-out
of --timeout), reconnecting when the session is lost, and prints one JSON object: reads
made, reads answered in time, the slowest answer, the first errors.

Run by crates/hartkit/tests/gateway_opcua.rs as a separate process, beside an abuser.
"""
import argparse
import asyncio
import json
import time

from asyncua import Client, ua

NS = "urn:hartkit:gateway:hart"


async def first_pv(c):
    ns = await c.get_namespace_index(NS)
    hart = await c.nodes.objects.get_child(["%d:HART" % ns])
    for folder in await hart.get_children():
        for dev in await folder.get_children():
            return await dev.get_child(["%d:PV" % ns])
    raise RuntimeError("no device under Objects/HART")


async def run(a):
    polls = answered = 0
    slowest = 0.0
    errors = []
    c = None
    pv = None
    end = time.time() + a.seconds
    while time.time() < end:
        t = time.time()
        polls += 1
        try:
            if c is None:
                c = Client(a.url, timeout=a.timeout)
                await asyncio.wait_for(c.connect(), a.timeout)
                pv = await first_pv(c)
            await asyncio.wait_for(pv.read_data_value(), a.timeout)
            answered += 1
            slowest = max(slowest, time.time() - t)
        except Exception as e:  # lost: reconnect on the next poll
            errors.append(type(e).__name__ + ": " + str(e)[:80])
            if c is not None:
                try:
                    await asyncio.wait_for(c.disconnect(), 2)
                except Exception:
                    pass
            c = None
        await asyncio.sleep(max(0.0, a.every - (time.time() - t)))
    if c is not None:
        await c.disconnect()
    print(json.dumps({"polls": polls, "answered": answered, "slowest_s": slowest, "errors": errors[:5]}))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--every", type=float, default=0.5)
    ap.add_argument("--timeout", type=float, default=3.0)
    a = ap.parse_args()
    import logging

    logging.disable(logging.CRITICAL)
    asyncio.run(run(a))


if __name__ == "__main__":
    main()

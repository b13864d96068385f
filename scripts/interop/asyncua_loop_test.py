#!/usr/bin/env python3
"""Starts a loop test through the gateway's OPC UA front end, as an outside client
(asyncua, LGPL) would: connects anonymously to `hartkit serve --opcua`, waits for the
devices of loop LOOP (Objects/HART/<LOOP>/<device>), calls LoopTest(MA) on the first
one, and prints one JSON object: {"loop_test": "ok" or the status code's name,
"device": its browse path}.

Run by crates/hartkit/tests/loop_test_release.rs as a separate process.
"""
import argparse
import asyncio
import json
import time

from asyncua import Client, ua


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--loop", required=True)
    ap.add_argument("--ma", type=float, required=True)
    ap.add_argument("--wait", type=float, default=60)
    a = ap.parse_args()
    out = {}
    async with Client(a.url, timeout=10) as c:
        ns = await c.get_namespace_index("urn:hartkit:gateway:hart")
        hart = await c.nodes.objects.get_child([f"{ns}:HART"])
        deadline = time.time() + a.wait
        device = None
        while device is None:
            try:
                lp = await hart.get_child([f"{ns}:{a.loop}"])
                children = await lp.get_children()
                if children:
                    device = children[0]
            except ua.UaStatusCodeError:
                pass
            if device is None:
                if time.time() > deadline:
                    break
                await asyncio.sleep(0.5)
        if device is None:
            out["loop_test"] = "no device"
        else:
            out["device"] = a.loop + "/" + (await device.read_browse_name()).Name
            try:
                await device.call_method(f"{ns}:LoopTest", ua.Variant(a.ma, ua.VariantType.Float))
                out["loop_test"] = "ok"
            except ua.UaStatusCodeError as e:
                out["loop_test"] = type(e).__name__
    print(json.dumps(out))


if __name__ == "__main__":
    asyncio.run(main())

#!/usr/bin/env python3
"""OPC UA subscription load (asyncua) for scripts/bench-gateway: ITEMS monitored items
on the changing variables (PV, SV, PercentRange) of every device behind a `hartkit serve
--opcua` gateway, spread evenly over the nodes, in one subscription publishing every
second; counts the data changes delivered over SECONDS and samples the gateway
process's CPU time (/proc/PID/stat) over the same window. Prints one JSON line.
"""
import argparse
import asyncio
import json
import os
import time

from asyncua import Client, ua


class Count:
    def __init__(self):
        self.n = 0

    def datachange_notification(self, node, val, data):
        self.n += 1


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    tick = os.sysconf("SC_CLK_TCK")
    return (int(fields[11]) + int(fields[12])) / tick


async def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--url", required=True)
    ap.add_argument("--pid", type=int, required=True)
    ap.add_argument("--items", type=int, default=10000)
    ap.add_argument("--seconds", type=float, default=30)
    a = ap.parse_args()
    async with Client(a.url, timeout=30) as c:
        ns = await c.get_namespace_index("urn:hartkit:gateway:hart")
        hart = await c.nodes.objects.get_child([f"{ns}:HART"])
        nodes = []
        for lp in await hart.get_children():
            for dev in await lp.get_children():
                for v in ("PV", "SV", "PercentRange"):
                    nodes.append(await dev.get_child([f"{ns}:{v}"]))
        handler = Count()
        sub = await c.create_subscription(1000, handler)
        items = [nodes[i % len(nodes)] for i in range(a.items)]
        for i in range(0, len(items), 1000):
            await sub.subscribe_data_change(items[i:i + 1000], queuesize=1)
        await asyncio.sleep(5)  # settle: the initial values
        handler.n = 0
        c0, t0 = cpu_seconds(a.pid), time.time()
        await asyncio.sleep(a.seconds)
        c1, t1 = cpu_seconds(a.pid), time.time()
        n = handler.n
        await sub.delete()
    print(json.dumps({
        "items": a.items,
        "nodes": len(nodes),
        "seconds": round(t1 - t0, 1),
        "changes_per_second": round(n / (t1 - t0)),
        "gateway_cpu_percent": round(100 * (c1 - c0) / (t1 - t0), 1),
    }))


if __name__ == "__main__":
    asyncio.run(main())

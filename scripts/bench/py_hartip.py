#!/usr/bin/env python3
"""HART-IP transactions per second from Python, one library per process (run by
scripts/bench-python against `hartkit serve --sim --instant`).

    python py_hartip.py hartkit|hartip-py HOST PORT [SECONDS [SESSIONS]]

Command 3 to the device at polling address 1 in a long frame, over UDP, the reply
decoded, one request after the other in each session (what a script does). With one
session: a plain loop. With more: hartkit with asyncio (one connection per session,
gathered), hartip-py (GPL-3.0) with one thread per session, since its client blocks.
hartkit uses its public API (hartkit.sync / hartkit.connect, read_dynamic()), hartip-py
HARTIPClient.send_command(3, unique_addr=...) and parse_cmd3. Prints one JSON object.
"""

import json
import sys
import threading
import time


def main() -> None:
    lib, host, port = sys.argv[1], sys.argv[2], int(sys.argv[3])
    seconds = float(sys.argv[4]) if len(sys.argv) > 4 else 5.0
    sessions = int(sys.argv[5]) if len(sys.argv) > 5 else 1
    target = f"udp://{host}:{port}"
    count = 0
    if lib == "hartkit" and sessions > 1:
        import asyncio

        import hartkit

        async def session(end: float) -> int:
            async with hartkit.connect(target) as loop:
                dev = await loop.device(poll=1)
                n = 0
                while time.perf_counter() < end:
                    r = await dev.read_dynamic()
                    r.variables[0].value
                    n += 1
                return n

        async def all_sessions() -> int:
            end = time.perf_counter() + seconds
            return sum(await asyncio.gather(*(session(end) for _ in range(sessions))))

        t0 = time.perf_counter()
        count = asyncio.run(all_sessions())
    else:
        if lib == "hartkit":
            import hartkit.sync

            def open_session():
                dev = hartkit.sync.connect(target).device(poll=1)
                return lambda: dev.read_dynamic().variables[0].value

        elif lib == "hartip-py":
            from hartip import HARTIPClient, parse_cmd0, parse_cmd3

            def open_session():
                client = HARTIPClient(host, port=port, protocol="udp")
                client.connect()
                uid = parse_cmd0(client.send_command(0, address=1).payload).unique_address
                return lambda: parse_cmd3(client.send_command(3, unique_addr=uid).payload)["variables"][0].value

        else:
            raise SystemExit(f"py_hartip.py: unknown library {lib!r}")
        transactions = [open_session() for _ in range(sessions)]
        counts = [0] * sessions
        t0 = time.perf_counter()
        end = t0 + seconds

        def worker(k: int) -> None:
            t = transactions[k]
            while time.perf_counter() < end:
                t()
                counts[k] += 1

        threads = [threading.Thread(target=worker, args=(k,)) for k in range(sessions)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        count = sum(counts)
    rate = count / (time.perf_counter() - t0)
    print(json.dumps({"library": lib, "sessions": sessions, "transactions_per_s": rate}))


if __name__ == "__main__":
    main()

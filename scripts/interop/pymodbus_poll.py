#!/usr/bin/env python3
"""A SCADA's poll (pymodbus, BSD): reads unit 1's quality register every --every
seconds for --seconds, reconnecting when the connection is lost, and prints one JSON
object: polls made, polls answered within the client's time-out, the slowest answer.

Run by crates/hartkit/tests/gateway_modbus.rs as a separate process, beside an abuser.
"""
import argparse
import json
import time

from pymodbus.client import ModbusTcpClient


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--every", type=float, default=0.5)
    ap.add_argument("--timeout", type=float, default=3.0)
    a = ap.parse_args()
    c = ModbusTcpClient("127.0.0.1", port=a.port, timeout=a.timeout, retries=0)
    polls = answered = 0
    slowest = 0.0
    errors = []
    end = time.time() + a.seconds
    while time.time() < end:
        polls += 1
        t = time.time()
        try:
            if not c.connected:
                c.connect()
            r = c.read_input_registers(13, count=1, device_id=1)
            if not r.isError():
                answered += 1
                slowest = max(slowest, time.time() - t)
            else:
                errors.append(str(r))
        except Exception as e:  # a lost connection: reconnect on the next poll
            errors.append(type(e).__name__)
            c.close()
        time.sleep(max(0.0, a.every - (time.time() - t)))
    c.close()
    print(json.dumps({"polls": polls, "answered": answered, "slowest_s": slowest, "errors": errors[:5]}))


if __name__ == "__main__":
    main()

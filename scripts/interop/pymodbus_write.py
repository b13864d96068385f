#!/usr/bin/env python3
"""One Modbus TCP write from a chosen source address (pymodbus, BSD), against
`hartkit serve --modbus`.

Run by crates/hartkit/tests/gateway_modbus.rs as a separate process, to check that
writes are taken only from the clients listed (--modbus-write-from). Connects from
--source, waits until the unit's quality is good, reads its damping (holding registers
4-5), writes --damping there, reads it back, and prints one JSON object: the
exception code of the write (null when it was done), the damping before, at once
after the write, and after waiting for it.
"""
import argparse
import json
import sys
import time

from pymodbus.client import ModbusTcpClient


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--source", required=True)
    ap.add_argument("--unit", type=int, default=1)
    ap.add_argument("--damping", type=float, required=True)
    a = ap.parse_args()
    c = ModbusTcpClient("127.0.0.1", port=a.port, timeout=10, source_address=(a.source, 0))
    if not c.connect():
        sys.exit(f"cannot connect from {a.source}")
    F32 = c.DATATYPE.FLOAT32
    deadline = time.time() + 60
    while time.time() < deadline:
        q = c.read_input_registers(13, count=1, device_id=a.unit)
        h = c.read_holding_registers(4, count=2, device_id=a.unit)
        if not q.isError() and q.registers[0] == 0 and not h.isError():
            break
        time.sleep(0.2)
    before = c.convert_from_registers(h.registers, data_type=F32)
    w = c.write_registers(4, c.convert_to_registers(a.damping, data_type=F32), device_id=a.unit)
    code = getattr(w, "exception_code", None) if w.isError() else None
    # The first read right after the write: the gateway shows what the device took.
    h = c.read_holding_registers(4, count=2, device_id=a.unit)
    at_once = None if h.isError() else c.convert_from_registers(h.registers, data_type=F32)
    after = before
    deadline = time.time() + (10 if code is None else 2)
    while time.time() < deadline:
        h = c.read_holding_registers(4, count=2, device_id=a.unit)
        if not h.isError():
            after = c.convert_from_registers(h.registers, data_type=F32)
            if code is None and abs(after - a.damping) < 1e-6:
                break
        time.sleep(0.2)
    c.close()
    print(json.dumps({"exception": code, "before": before, "after": after, "at_once": at_once}))


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""An outside Modbus RTU master (pymodbus with pyserial) against `hartkit serve
--modbus-rtu`, on one end of a pseudo-terminal pair whose other end the gateway has.

Run by crates/hartkit/tests/gateway_modbus.rs as a separate process. Reads unit 1,
asks a unit id the gateway does not have (an RTU slave must stay silent: another slave
may own it), writes a damping value to every unit by broadcast (unit 0, no answer) and
reads it back from units 1 and 2. Prints one JSON object.
"""
import argparse
import json
import time

from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusIOException


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", required=True)
    ap.add_argument("--damping", type=float, default=3.0)
    a = ap.parse_args()
    c = ModbusSerialClient(a.device, baudrate=19200, parity="N", stopbits=1, timeout=1, retries=0)
    if not c.connect():
        raise SystemExit("cannot open " + a.device)
    F32 = c.DATATYPE.FLOAT32
    out = {}
    deadline = time.time() + 20
    while True:
        r = c.read_input_registers(0, count=16, device_id=1)
        if (not r.isError() and r.registers[13] == 0) or time.time() > deadline:
            break
        time.sleep(0.2)
    out["pv_units"] = None if r.isError() else r.registers[10]
    out["quality"] = None if r.isError() else r.registers[13]
    try:
        r = c.read_input_registers(0, count=2, device_id=200)
        out["unknown_unit"] = "answered: " + str(r)
    except ModbusIOException:
        out["unknown_unit"] = "silent"
    c.write_registers(4, c.convert_to_registers(a.damping, data_type=F32), device_id=0,
                      no_response_expected=True)
    # The next request is answered at once: the broadcast's writes go on meanwhile.
    t = time.time()
    q = c.read_input_registers(13, count=1, device_id=1)
    out["after_broadcast_s"] = None if q.isError() else time.time() - t
    back = {}
    deadline = time.time() + 20
    while time.time() < deadline:
        for unit in (1, 2):
            h = c.read_holding_registers(4, count=2, device_id=unit)
            back[str(unit)] = None if h.isError() else c.convert_from_registers(h.registers, data_type=F32)
        if all(v == a.damping for v in back.values()):
            break
        time.sleep(0.2)
    out["damping"] = back
    c.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main()

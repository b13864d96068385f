#!/usr/bin/env python3
"""An outside Modbus TCP client (pymodbus, BSD) against `hartkit serve --modbus`.

Run by crates/hartkit/tests/gateway_modbus.rs as a separate process. Waits until
units 1..N report quality 0 (good), reads every unit's input and holding registers
and decodes the floats with pymodbus's own converter, provokes the exceptions a SCADA
meets (unknown unit, register outside the map, half a float, unsupported function,
a value the device refuses), writes a damping value, and prints one JSON object.
"""
import argparse
import json
import struct
import sys
import time

from pymodbus.client import ModbusTcpClient


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--units", type=int, required=True)
    ap.add_argument("--write-unit", type=int, default=1)
    ap.add_argument("--damping", type=float, default=2.5)
    ap.add_argument("--wait", type=float, default=90.0)
    ap.add_argument("--word-order", default="big", choices=["big", "little"])
    a = ap.parse_args()
    c = ModbusTcpClient("127.0.0.1", port=a.port, timeout=10)
    if not c.connect():
        sys.exit("cannot connect")
    F32 = c.DATATYPE.FLOAT32
    U32 = c.DATATYPE.UINT32

    def f32(regs):
        return c.convert_from_registers(regs, data_type=F32, word_order=a.word_order)

    def u32(regs):
        return c.convert_from_registers(regs, data_type=U32, word_order=a.word_order)

    out = {"units": []}
    deadline = time.time() + a.wait
    while True:
        qualities = []
        for unit in range(1, a.units + 1):
            r = c.read_input_registers(13, count=1, device_id=unit)
            qualities.append(None if r.isError() else r.registers[0])
        if all(q == 0 for q in qualities) or time.time() > deadline:
            break
        time.sleep(0.5)
    out["qualities"] = qualities

    for unit in range(1, a.units + 1):
        r = c.read_input_registers(0, count=26, device_id=unit)
        h = c.read_holding_registers(0, count=9, device_id=unit)
        if r.isError() or h.isError():
            out["units"].append({"unit": unit, "error": str(r if r.isError() else h)})
            continue
        g = r.registers
        k = h.registers
        out["units"].append({
            "unit": unit,
            "pv": f32(g[0:2]), "sv": f32(g[2:4]), "tv": f32(g[4:6]), "qv": f32(g[6:8]),
            "loop_current": f32(g[8:10]),
            "pv_units": g[10], "device_status": g[11], "extended_status": g[12],
            "quality": g[13], "age": u32(g[14:16]), "percent_range": f32(g[16:18]),
            "sv_units": g[18], "polling_address": g[21], "device_id": u32(g[22:24]),
            "manufacturer_id": g[24], "device_type": g[25],
            "upper_range": f32(k[0:2]), "lower_range": f32(k[2:4]),
            "damping": f32(k[4:6]), "fixed_current": f32(k[6:8]), "range_units": k[8],
        })

    def exception(r):
        return getattr(r, "exception_code", None) if r.isError() else None

    out["unknown_unit"] = exception(c.read_input_registers(0, count=2, device_id=a.units + 1))
    out["outside_map"] = exception(c.read_input_registers(26, count=1, device_id=1))
    out["read_coils"] = exception(c.read_coils(0, count=1, device_id=1))
    out["half_float"] = exception(c.write_register(4, 0x4020, device_id=a.write_unit))
    out["write_input"] = exception(c.write_registers(9, [1, 2], device_id=a.write_unit))

    def words(x):
        return c.convert_to_registers(x, data_type=F32, word_order=a.word_order)

    # A negative damping: the device refuses it (too small).
    out["bad_damping"] = exception(c.write_registers(4, words(-1.0), device_id=a.write_unit))
    w = c.write_registers(4, words(a.damping), device_id=a.write_unit)
    out["write_damping"] = exception(w) if w.isError() else "ok"
    back = None
    deadline = time.time() + 30
    while time.time() < deadline:
        h = c.read_holding_registers(4, count=2, device_id=a.write_unit)
        if not h.isError():
            back = f32(h.registers)
            if abs(back - a.damping) < 1e-6:
                break
        time.sleep(0.2)
    out["damping_read_back"] = back
    c.close()

    def clean(v):
        # NaN (no value) is not JSON: null.
        if isinstance(v, float) and v != v:
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list):
            return [clean(x) for x in v]
        return v

    print(json.dumps(clean(out)))


if __name__ == "__main__":
    main()

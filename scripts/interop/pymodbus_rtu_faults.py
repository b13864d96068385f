#!/usr/bin/env python3
"""The faults of issue 30 on a Modbus RTU line, against `hartkit serve --modbus-rtu` on
one end of a pseudo-terminal pair: pymodbus (with pyserial) is the master on the other
end, and a second pyserial handle on the same end writes the bad bytes.

Each fault is followed by good requests (read input registers of unit 1) every 0.4 s,
as the issue's master sent them: a function-16 frame cut short after its byte count,
a valid reply frame of another slave (unit 5, function 3), 1000 random bytes. With
`--flood SECONDS`, a master that sends bursts of junk between its good requests for
that long. Run by crates/hartkit/tests/gateway_modbus.rs as a separate process. Prints
one JSON object: per fault, the good requests sent, those answered, and the slowest
answer in seconds.
"""
import argparse
import json
import random
import time

import serial
from pymodbus.client import ModbusSerialClient
from pymodbus.exceptions import ModbusException


def crc16(data):
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def adu(unit, pdu):
    body = bytes([unit]) + bytes(pdu)
    return body + crc16(body).to_bytes(2, "little")


def good_request(c):
    """A read of unit 1: the seconds it took, or None if it was not answered."""
    t = time.time()
    try:
        r = c.read_input_registers(0, count=16, device_id=1)
    except ModbusException:
        return None
    return None if r.isError() else time.time() - t


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", required=True)
    ap.add_argument("--requests", type=int, default=5)
    ap.add_argument("--flood", type=float, default=0)
    a = ap.parse_args()
    c = ModbusSerialClient(a.device, baudrate=19200, parity="N", stopbits=1, timeout=1, retries=0)
    if not c.connect():
        raise SystemExit("cannot open " + a.device)
    raw = serial.Serial(a.device, baudrate=19200)
    rng = random.Random(30)
    deadline = time.time() + 20
    while good_request(c) is None and time.time() < deadline:
        time.sleep(0.2)
    faults = {
        # Write multiple registers 4-5 of unit 1, cut after its byte count.
        "cut_function_16": bytes([1, 0x10, 0, 4, 0, 2, 4]),
        # Unit 5's reply to a read of 2 holding registers.
        "foreign_reply": adu(5, [3, 4, 0x12, 0x34, 0x56, 0x78]),
        "random_1000": bytes(rng.randrange(256) for _ in range(1000)),
    }
    out = {}
    for name, junk in faults.items():
        raw.write(junk)
        raw.flush()
        times = []
        for _ in range(a.requests):
            time.sleep(0.4)
            times.append(good_request(c))
        answered = [t for t in times if t is not None]
        out[name] = {
            "sent": len(times),
            "answered": len(answered),
            "slowest_s": max(answered, default=None),
            "times": times,
        }
    if a.flood > 0:
        sent, answered, slowest, junk_bytes, lost = 0, 0, 0.0, 0, []
        end = time.time() + a.flood
        while time.time() < end:
            junk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
            raw.write(junk)
            raw.flush()
            junk_bytes += len(junk)
            # A silence (well over t3.5) between the junk and the request.
            time.sleep(0.02)
            t = good_request(c)
            sent += 1
            if t is not None:
                answered += 1
                slowest = max(slowest, t)
            else:
                lost.append(sent)
        out["flood"] = {
            "sent": sent,
            "answered": answered,
            "slowest_s": slowest,
            "junk_bytes": junk_bytes,
            "lost": lost,
        }
    raw.close()
    c.close()
    print(json.dumps(out))


if __name__ == "__main__":
    main()

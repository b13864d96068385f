#!/usr/bin/env python3
"""Churning clients for the gateway soak (scripts/soak-gateway): for --seconds, each
round opens a Modbus TCP connection with pymodbus (BSD), reads unit 1's quality and
PV, and closes it; and opens a HART-IP session with hartip-py (GPL-3.0, run as a
separate process, never imported by hartkit), over TCP and UDP in turn, sends command
0 at polling address 0, and closes it. Prints one JSON line every --report seconds:
rounds made, rounds that failed, and the last failure.

Usage: churn.py --modbus PORT --hart-ip PORT [--seconds S] [--every S] [--report S]
"""
import argparse
import json
import time

from hartip import HARTIPClient
from pymodbus.client import ModbusTcpClient


def modbus_round(port):
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=3, retries=0)
    try:
        if not c.connect():
            raise RuntimeError("modbus: no connection")
        r = c.read_input_registers(0, count=14, device_id=1)
        if r.isError():
            raise RuntimeError(f"modbus: {r}")
    finally:
        c.close()


def hartip_round(port, protocol):
    c = HARTIPClient("127.0.0.1", port=port, protocol=protocol, timeout=3.0)
    try:
        c.connect()
        r = c.send_command(0, address=0, unique_addr=None)
        if not r.success:
            raise RuntimeError(f"hart-ip {protocol}: command 0 answered {r.response_code}")
    finally:
        c.close()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--modbus", type=int, required=True)
    ap.add_argument("--hart-ip", type=int, required=True)
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--every", type=float, default=0.05)
    ap.add_argument("--report", type=float, default=10.0)
    a = ap.parse_args()
    end = time.time() + a.seconds
    next_report = time.time() + a.report
    rounds = failed = 0
    last = None
    while time.time() < end:
        rounds += 1
        try:
            modbus_round(a.modbus)
            hartip_round(a.hart_ip, "tcp" if rounds % 2 else "udp")
        except Exception as e:  # noqa: BLE001 - every failure is counted and shown
            failed += 1
            last = str(e)
        time.sleep(a.every)
        if time.time() >= next_report:
            print(json.dumps({"rounds": rounds, "failed": failed, "last_failure": last}), flush=True)
            next_report += a.report
    print(json.dumps({"rounds": rounds, "failed": failed, "last_failure": last, "done": True}), flush=True)


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Interop check: drive hartkit's HART-IP server with an outside client, hartip-py.

hartip-py (PyPI ``hartip-py``, import name ``hartip``) is a third-party HART-IP
client library licensed GPL-3.0. It is NOT a dependency of hartkit: nothing in
the crates imports or ships it. Install it in a throwaway venv and run this
script with that venv's python, as a separate process:

    python3 -m venv /tmp/hipvenv && /tmp/hipvenv/bin/pip install hartip-py
    /tmp/hipvenv/bin/python scripts/interop/hartip_py_client.py \
        --host 127.0.0.1 --port 5094 --transport udp      # or tcp

Sessions, HART-IP framing, PDU building/checking and the parsers for commands
0, 1 and 3 all come from hartip-py (HARTIPClient.connect/send_command/close,
parse_cmd0/1/3), so the server is judged by an implementation that shares no
code with hartkit. hartip-py has no parser for command 84 and decodes the
command 20 long tag as ASCII, so those two payloads are decoded here (from the
``payload`` bytes hartip-py returns after checking the frame); command 84's
request data (the u16 index) is passed through ``send_command(data=...)``.
Long frames and TCP are native in hartip-py (``unique_addr=``, ``protocol=``);
no PDU bytes are hand-built.

Steps (one JSON object per line on stdout):
  session   HART-IP Session Initiate (hartip-py connect()).
  cmd0      command 0, short frame, polling address 0: identity.
  sub       if that device is an I/O system (device profile 4 or 68, or the
            cmd 0 flags bit 0x04 "protocol bridge"): command 84 (long frame to
            the I/O system) for index 0, 1, ... until response code 2 (invalid
            selection), another error, or 64 entries.
  cmd0      (I/O system only) command 0 short frame to polling addresses 1..3.
  cmd1, cmd3, cmd20
            long frames to a field device: the first sub-device from command 84
            (then the next ones, then the devices found at polls 1..3, until one
            answers all three), or the poll-0 device if it is not an I/O system.
  result    summary.

Exit code 0 only if command 0 at poll 0 answered with response code 0 AND a
field device answered commands 1, 3 and 20 with response code 0. With
--unique-id HEX10 discovery (cmd 0 / 84 / polls) is skipped and only the
long-frame commands to that address count. Exit 1 otherwise (reason on
stderr), 2 for bad arguments.

Each request is bounded to --timeout seconds (default 5) in total, including
hartip-py's delayed-response retries (SIGALRM guard around each call).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from contextlib import contextmanager

try:
    from hartip import HARTIPClient, parse_cmd0, parse_cmd1, parse_cmd3
    from hartip.exceptions import HARTError
except ImportError as exc:  # pragma: no cover - environment problem
    print(
        f"hartip_py_client: cannot import hartip-py ({exc}); run this script with the "
        "python of a venv where `pip install hartip-py` was done",
        file=sys.stderr,
    )
    sys.exit(3)

RC_INVALID_SELECTION = 2
IO_SYSTEM_PROFILES = (4, 68)  # Common Table 57: I/O system, HART-IP I/O system
FLAG_PROTOCOL_BRIDGE = 0x04  # cmd 0 flags byte
MAX_SUBS = 64
CMD84_LEN = 48


class RequestTimeout(Exception):
    """The per-request wall-clock budget ran out."""


def emit(obj: dict) -> None:
    print(json.dumps(obj, ensure_ascii=False), flush=True)


def num(x: float) -> float | str:
    """JSON-safe float: NaN / infinities as strings (HART uses NaN for 'no value')."""
    return x if math.isfinite(x) else str(x)


def unique_id(edt: int, device_id: int) -> bytes:
    """5-byte long address: primary-master bit, 6 bits of the expanded device type's
    high byte, its low byte, then the 3-byte device ID."""
    return bytes([0x80 | ((edt >> 8) & 0x3F), edt & 0xFF]) + device_id.to_bytes(3, "big")


@contextmanager
def deadline(seconds: float):
    """Hard wall-clock cap on one request (socket waits and DR retries together)."""

    def fire(_sig, _frame):
        raise RequestTimeout(f"no complete answer within {seconds:g} s")

    old = signal.signal(signal.SIGALRM, fire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


class Runner:
    def __init__(self, client: HARTIPClient, timeout: float):
        self.client = client
        self.timeout = timeout

    def request(self, command: int, *, poll: int | None = None, uid: bytes | None = None,
                data: bytes = b""):
        """One HART command through hartip-py: (response, error string, seconds taken)."""
        t0 = time.monotonic()
        try:
            with deadline(self.timeout):
                if uid is not None:
                    resp = self.client.send_command(command, data=data, unique_addr=uid)
                else:
                    # unique_addr=None: short frame even though read_unique_id() may
                    # have set the client's default long address.
                    resp = self.client.send_command(command, address=poll or 0, data=data,
                                                    unique_addr=None)
        except (HARTError, RequestTimeout, OSError, ValueError) as exc:
            return None, f"{type(exc).__name__}: {exc}", time.monotonic() - t0
        return resp, None, time.monotonic() - t0


def base(step: str, resp, err, elapsed: float, **addr) -> dict:
    out: dict = {"step": step, **addr, "ms": round(elapsed * 1000, 1)}
    if err is not None:
        out.update(ok=False, error=err)
        return out
    out.update(
        ok=resp.success,
        response_code=resp.response_code,
        comm_error=resp.comm_error,
        device_status=resp.device_status,
    )
    if not resp.success:
        out["error"] = resp.error_message
    return out


def identity(payload: bytes) -> dict:
    info = parse_cmd0(payload)  # hartip-py's parser
    uid = unique_id(info.expanded_device_type, info.device_id)
    d = {
        "expanded_device_type": f"0x{info.expanded_device_type:04X}",
        "device_id": f"0x{info.device_id:06X}",
        "device_profile": info.device_profile,
        "flags": f"0x{info.flags:02X}",
        "universal_revision": info.hart_revision,
        "device_revision": info.device_revision,
        "manufacturer_id": f"0x{info.manufacturer_id_16bit:04X}",
        "private_label": f"0x{info.private_label:04X}",
        "unique_id": uid.hex(),
    }
    if info.unique_address and info.unique_address != uid:
        # hartip-py builds the long address too; flag any disagreement.
        d["hartip_py_unique_id"] = info.unique_address.hex()
    return d, info, uid


def is_io_system(info) -> bool:
    return info.device_profile in IO_SYSTEM_PROFILES or bool(info.flags & FLAG_PROTOCOL_BRIDGE)


def parse_cmd84(p: bytes) -> dict | None:
    if len(p) < CMD84_LEN:
        return None
    edt = int.from_bytes(p[6:8], "big")
    dev_id = int.from_bytes(p[8:11], "big")
    return {
        "sub_index": int.from_bytes(p[0:2], "big"),
        "card": p[2],
        "channel": p[3],
        "manufacturer_id": f"0x{int.from_bytes(p[4:6], 'big'):04X}",
        "expanded_device_type": f"0x{edt:04X}",
        "device_id": f"0x{dev_id:06X}",
        "universal_revision": p[11],
        "long_tag": p[12:44].decode("latin-1").rstrip("\x00 "),
        "device_revision": p[44],
        "device_profile": p[45],
        "private_label": f"0x{int.from_bytes(p[46:48], 'big'):04X}",
        "unique_id": unique_id(edt, dev_id).hex(),
    }


def read_field_device(r: Runner, uid: bytes) -> bool:
    """Commands 1, 3, 20 as long frames; True if all three answer with code 0."""
    addr = {"unique_id": uid.hex()}
    all_ok = True

    resp, err, el = r.request(1, uid=uid)
    out = base("cmd1", resp, err, el, **addr)
    if err is None and resp.response_code == 0:
        pv = parse_cmd1(resp.payload)
        if pv is None:
            out.update(ok=False, error=f"short payload ({len(resp.payload)} bytes)")
        else:
            out.update(pv_unit_code=pv.unit_code, pv_unit=pv.unit_name, pv=num(pv.value))
    all_ok &= bool(out["ok"])
    emit(out)

    resp, err, el = r.request(3, uid=uid)
    out = base("cmd3", resp, err, el, **addr)
    if err is None and resp.response_code == 0:
        dv = parse_cmd3(resp.payload)
        if not dv:
            out.update(ok=False, error=f"short payload ({len(resp.payload)} bytes)")
        else:
            out["loop_current_mA"] = num(dv["loop_current"])
            out["variables"] = [
                {"slot": v.label, "unit_code": v.unit_code, "unit": v.unit_name,
                 "value": num(v.value)}
                for v in dv["variables"]
            ]
    all_ok &= bool(out["ok"])
    emit(out)

    resp, err, el = r.request(20, uid=uid)
    out = base("cmd20", resp, err, el, **addr)
    if err is None and resp.response_code == 0:
        if len(resp.payload) < 32:
            out.update(ok=False, error=f"short payload ({len(resp.payload)} bytes)")
        else:
            # Latin-1 per the spec (hartip-py's parse_cmd20 decodes ASCII).
            out["long_tag"] = resp.payload[:32].decode("latin-1").rstrip("\x00 ")
    all_ok &= bool(out["ok"])
    emit(out)
    return all_ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--transport", choices=("udp", "tcp"), default="udp")
    ap.add_argument("--timeout", type=float, default=5.0,
                    help="seconds per request, all retries included (default 5)")
    ap.add_argument("--unique-id", metavar="HEX10",
                    help="skip discovery; send commands 1, 3, 20 to this 5-byte long address "
                         "(e.g. 26F1010002 as `hartkit scan` prints it; the primary-master "
                         "bit is set for you)")
    args = ap.parse_args()

    fixed_uid = None
    if args.unique_id is not None:
        try:
            fixed_uid = bytes.fromhex(args.unique_id)
        except ValueError:
            fixed_uid = b""
        if len(fixed_uid) != 5:
            ap.error("--unique-id takes 10 hex digits (5 bytes)")
        # Accept the unique ID as hartkit prints it (no master bit): set the
        # primary-master bit, clear the burst bit, as in the discovered addresses.
        fixed_uid = bytes([0x80 | (fixed_uid[0] & 0x3F)]) + fixed_uid[1:]

    client = HARTIPClient(
        args.host,
        args.port,
        protocol=args.transport,
        timeout=args.timeout,
        dr_retries=10,  # the SIGALRM guard bounds the total anyway
        dr_retry_delay=50,
    )
    try:
        with deadline(args.timeout):
            client.connect()
    except (HARTError, RequestTimeout, OSError) as exc:
        emit({"step": "session", "ok": False, "transport": args.transport,
              "error": f"{type(exc).__name__}: {exc}"})
        print(f"hartip_py_client: no HART-IP session with {args.host}:{args.port} "
              f"over {args.transport}: {exc}", file=sys.stderr)
        return 1
    emit({"step": "session", "ok": True, "transport": args.transport,
          "server_version": client.server_version})

    r = Runner(client, args.timeout)
    try:
        return run(r, args, fixed_uid)
    finally:
        try:
            with deadline(args.timeout):
                client.close()
        except RequestTimeout:
            pass


def run(r: Runner, args, fixed_uid: bytes | None) -> int:
    failures: list[str] = []
    poll0_ok = False
    field_ok = False
    tried: list[str] = []

    if fixed_uid is not None:
        field_ok = read_field_device(r, fixed_uid)
        tried.append(fixed_uid.hex())
        if not field_ok:
            failures.append(f"device {fixed_uid.hex()} did not answer commands 1, 3 and 20 "
                            "with response code 0")
        emit({"step": "result", "ok": field_ok, "discovery": "skipped (--unique-id)",
              "field_device_ok": field_ok, "tried": tried})
    else:
        candidates: list[bytes] = []
        resp, err, el = r.request(0, poll=0)
        out = base("cmd0", resp, err, el, poll=0, frame="short")
        info = None
        if err is None and resp.response_code == 0:
            if len(resp.payload) < 12:
                out.update(ok=False, error=f"short payload ({len(resp.payload)} bytes)")
            else:
                ident, info, uid0 = identity(resp.payload)
                out.update(ident)
                out["io_system"] = is_io_system(info)
        emit(out)
        poll0_ok = bool(out["ok"])
        if not poll0_ok:
            failures.append(f"command 0 at polling address 0 failed: {out.get('error')}")

        if info is not None and is_io_system(info):
            for ix in range(MAX_SUBS):
                resp, err, el = r.request(84, uid=uid0, data=ix.to_bytes(2, "big"))
                if err is None and resp.response_code == RC_INVALID_SELECTION:
                    emit({"step": "sub", "index": ix, "end": True, "response_code": 2,
                          "ms": round(el * 1000, 1)})
                    break
                out = base("sub", resp, err, el, index=ix)
                if err is None and resp.response_code == 0:
                    sub = parse_cmd84(resp.payload)
                    if sub is None:
                        out.update(ok=False, error=f"short payload ({len(resp.payload)} bytes)")
                    else:
                        out.update(sub)
                        if sub["unique_id"] == uid0.hex():
                            out["self"] = True  # the I/O system listed itself
                        else:
                            candidates.append(bytes.fromhex(sub["unique_id"]))
                emit(out)
                if not out["ok"]:
                    break
            for poll in (1, 2, 3):
                resp, err, el = r.request(0, poll=poll)
                out = base("cmd0", resp, err, el, poll=poll, frame="short")
                if err is None and resp.response_code == 0 and len(resp.payload) >= 12:
                    ident, _info, uid = identity(resp.payload)
                    out.update(ident)
                    out["answered"] = True
                    if uid not in candidates:
                        candidates.append(uid)
                else:
                    out["answered"] = False
                emit(out)
            if not candidates:
                failures.append("the I/O system listed no sub-device (command 84) and no "
                                "device answered at polling addresses 1..3")
        elif info is not None:
            candidates.append(uid0)

        for uid in candidates:
            tried.append(uid.hex())
            if read_field_device(r, uid):
                field_ok = True
                break
        if candidates and not field_ok:
            failures.append("no field device answered commands 1, 3 and 20 with response "
                            f"code 0 (tried {', '.join(tried)})")
        ok = poll0_ok and field_ok
        emit({"step": "result", "ok": ok, "poll0_ok": poll0_ok, "field_device_ok": field_ok,
              "tried": tried})

    if failures or not (field_ok and (fixed_uid is not None or poll0_ok)):
        for f in failures or ["interop check failed"]:
            print(f"hartip_py_client: FAIL: {f}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""Independent HART token-passing frame decoder, used only as a test oracle.

Written from docs/hart-reference.md (sections 2, 3, 4, 6, 7, 9, 10, 13) and
the oracle contract alone, without looking at the hartkit Rust sources.
Python 3.11, standard library only.

Usage:
    python3 hart_oracle.py             read hex frames from stdin, one per line,
                                       print one JSON object per line
    python3 hart_oracle.py --selftest  check the worked examples of section 13
                                       and fuzz the decoder with random input

Input line: hex digits, optionally separated by spaces, tabs or colons, any
case. A frame may start with any number (including 0) of 0xFF preamble bytes
and may carry extra bytes after the check byte.

Output line: either the decoded frame or {"error": "<short reason>"}.
"""

import json
import math
import random
import struct
import sys

FRAME_TYPES = {1: "BACK", 2: "STX", 6: "ACK"}
HEXDIGITS = frozenset("0123456789abcdefABCDEF")
SEPARATORS = frozenset(" \t:\r\n")


class FrameError(Exception):
    """The input is not a decodable frame; str(exc) is the short reason."""


# ---------------------------------------------------------------- helpers

def hexu(b):
    """Uppercase hex, no separators."""
    return bytes(b).hex().upper()


def u16(b, i):
    return (b[i] << 8) | b[i + 1]


def u32(b, i):
    return (b[i] << 24) | (b[i + 1] << 16) | (b[i + 2] << 8) | b[i + 3]


def f32(b, i):
    """Big-endian IEEE-754 single as a Python float; NaN/inf -> None."""
    v = struct.unpack(">f", bytes(b[i:i + 4]))[0]
    return v if math.isfinite(v) else None


def packed_ascii(b):
    """Packed ASCII (section 10.1): every 3 bytes -> 4 six-bit characters."""
    out = []
    for i in range(0, len(b) - len(b) % 3, 3):
        w = (b[i] << 16) | (b[i + 1] << 8) | b[i + 2]
        for shift in (18, 12, 6, 0):
            v = (w >> shift) & 0x3F
            out.append(chr(v | (((v & 0x20) ^ 0x20) << 1)))
    return "".join(out).rstrip(" \x00")


def latin1(b):
    return bytes(b).decode("latin-1").rstrip(" \x00")


def parse_hex_line(line):
    """Text line -> bytes. Raises FrameError on anything but hex/separators."""
    digits = []
    for ch in line:
        if ch in SEPARATORS:
            continue
        if ch not in HEXDIGITS:
            raise FrameError("invalid hex")
        digits.append(ch)
    if not digits:
        raise FrameError("empty")
    if len(digits) % 2:
        raise FrameError("odd number of hex digits")
    return bytes.fromhex("".join(digits))


# ---------------------------------------------------------------- frame

def decode_frame(raw):
    """Decode one frame (bytes) into the oracle dict. Raises FrameError."""
    raw = bytes(raw)
    n = len(raw)
    pos = 0
    while pos < n and raw[pos] == 0xFF:
        pos += 1
    preambles = pos
    if pos >= n:
        raise FrameError("no delimiter")

    delim = raw[pos]
    ftype = FRAME_TYPES.get(delim & 0x07)
    if ftype is None:
        raise FrameError("invalid delimiter")
    pos += 1
    start = pos - 1  # checksum starts at the delimiter

    long_addr = bool(delim & 0x80)
    addr_len = 5 if long_addr else 1
    exp_len = (delim >> 5) & 0x03

    # address + expansion + command + byte count must all be present
    if n < pos + addr_len + exp_len + 2:
        raise FrameError("truncated")
    addr = raw[pos:pos + addr_len]
    pos += addr_len
    expansion = raw[pos:pos + exp_len]
    pos += exp_len
    cmd_byte = raw[pos]
    byte_count = raw[pos + 1]
    pos += 2

    is_reply = ftype in ("ACK", "BACK")
    if is_reply and byte_count < 2:
        raise FrameError("byte count < 2 for ACK/BACK")
    if n < pos + byte_count + 1:
        raise FrameError("truncated")

    body = raw[pos:pos + byte_count]
    check = raw[pos + byte_count]
    trailing = raw[pos + byte_count + 1:]

    calc = 0
    for b in raw[start:pos + byte_count]:
        calc ^= b

    # ---- address
    a0 = addr[0]
    address = {
        "type": "long" if long_addr else "short",
        "master": "primary" if a0 & 0x80 else "secondary",
        "burst": bool(a0 & 0x40),
    }
    if long_addr:
        uid = bytes([a0 & 0x3F]) + addr[1:5]
        address["unique_id"] = hexu(uid)
        address["expanded_device_type"] = ((a0 & 0x3F) << 8) | addr[1]
        address["device_id"] = hexu(addr[2:5])
        address["broadcast"] = not any(uid)
    else:
        address["polling_address"] = a0 & 0x3F

    # ---- status bytes
    if is_reply:
        rc, ds = body[0], body[1]
        data = body[2:]
    else:
        rc = ds = None
        data = body

    # ---- command 31 expansion
    command = cmd_byte
    if cmd_byte == 31 and len(data) >= 2:
        command = u16(data, 0)
        data = data[2:]

    out = {
        "preambles": preambles,
        "delimiter": delim,
        "frame_type": ftype,
        "address": address,
        "expansion": hexu(expansion),
        "command": command,
    }
    if cmd_byte == 31:
        out["command_byte"] = 31
    out["byte_count"] = byte_count
    comm_error = False
    if is_reply:
        comm_error = bool(rc & 0x80)
        out["response_code"] = rc
        out["device_status"] = ds
        out["communication_error"] = comm_error
    out["data"] = hexu(data)
    out["checksum_ok"] = calc == check
    out["trailing"] = hexu(trailing)

    if not comm_error:
        dec = decode_reply(command, data) if is_reply else decode_request(command, data)
        if dec is not None:
            out["decoded"] = dec
    return out


# ---------------------------------------------------------------- replies

def decode_identity(d):
    """Cmd 0 / 11 / 21 reply body (>= 12 bytes)."""
    r = {
        "expanded_device_type": u16(d, 1),
        "min_request_preambles": d[3],
        "universal_revision": d[4],
        "device_revision": d[5],
        "software_revision": d[6],
        "hardware_revision": d[7] >> 3,
        "physical_signaling": d[7] & 0x07,
        "flags": d[8],
        "device_id": hexu(d[9:12]),
    }
    if len(d) >= 17:
        r["min_response_preambles"] = d[12]
        r["max_device_variables"] = d[13]
        r["config_change_counter"] = u16(d, 14)
        r["extended_status"] = d[16]
    if len(d) >= 22:
        r["manufacturer_id"] = u16(d, 17)
        r["private_label_distributor"] = u16(d, 19)
        r["device_profile"] = d[21]
    if d[4] <= 5 and "manufacturer_id" not in r:
        # HART 5 layout: byte 1 manufacturer, byte 2 device type. In the odd reply
        # that says revision 5 or older and still carries bytes 17-18, those bytes
        # are the manufacturer ID (the project's documented reading, hart-proto's
        # identity_legacy_fields: a 16-bit code a device sent is not hidden).
        r["manufacturer_id"] = d[1]
        r["device_type"] = d[2]
    return r


def decode_reply(cmd, d):
    n = len(d)
    if cmd in (0, 11, 21):
        return decode_identity(d) if n >= 12 else None
    if cmd == 1:
        return {"pv_units": d[0], "pv": f32(d, 1)} if n >= 5 else None
    if cmd == 2:
        if n < 8:
            return None
        return {"loop_current": f32(d, 0), "percent_of_range": f32(d, 4)}
    if cmd == 3:
        if n < 4:
            return None
        variables = []
        i = 4
        while i + 5 <= n and len(variables) < 4:
            variables.append({"units": d[i], "value": f32(d, i + 1)})
            i += 5
        return {"loop_current": f32(d, 0), "variables": variables}
    if cmd == 9:
        if n < 1:
            return None
        r = {"extended_status": d[0]}
        slots = []
        i = 1
        while i + 8 <= n and len(slots) < 8:
            slots.append({
                "code": d[i],
                "classification": d[i + 1],
                "units": d[i + 2],
                "value": f32(d, i + 3),
                "status": d[i + 7],
            })
            i += 8
        r["slots"] = slots
        if n - i == 4:
            r["timestamp"] = u32(d, i)
        return r
    if cmd == 12:
        return {"message": packed_ascii(d[0:24])} if n >= 24 else None
    if cmd == 13:
        if n < 21:
            return None
        return {
            "tag": packed_ascii(d[0:6]),
            "descriptor": packed_ascii(d[6:18]),
            "date": "%04d-%02d-%02d" % (1900 + d[20], d[19], d[18]),
        }
    if cmd == 20:
        return {"long_tag": latin1(d[0:32])} if n >= 32 else None
    if cmd == 48:
        return {"additional_status": hexu(d)} if n >= 1 else None
    return None


# ---------------------------------------------------------------- requests

def decode_request(cmd, d):
    n = len(d)
    if cmd == 6:
        if n < 1:
            return None
        r = {"polling_address": d[0]}
        if n >= 2:
            r["loop_current_mode"] = d[1]
        return r
    if cmd == 9:
        return {"slots": list(d[0:8])} if n >= 1 else None
    if cmd == 11:
        return {"tag": packed_ascii(d[0:6])} if n >= 6 else None
    if cmd == 21:
        return {"long_tag": latin1(d[0:32])} if n >= 32 else None
    if cmd == 38:
        return {"config_change_counter": u16(d, 0)} if n >= 2 else None
    return None


# ---------------------------------------------------------------- driver

def decode_line(line):
    """Text line -> JSON-ready dict; never raises."""
    try:
        return decode_frame(parse_hex_line(line))
    except FrameError as e:
        return {"error": str(e)}
    except Exception as e:  # pragma: no cover - defensive, must never crash
        return {"error": "internal: %s" % type(e).__name__}


def to_json(obj):
    try:
        return json.dumps(obj, allow_nan=False)
    except Exception as e:  # pragma: no cover
        return json.dumps({"error": "internal: %s" % type(e).__name__})


def main_stream():
    out = sys.stdout
    for raw_line in sys.stdin.buffer:
        try:
            line = raw_line.decode("latin-1")
        except Exception:  # pragma: no cover
            line = ""
        try:
            out.write(to_json(decode_line(line)) + "\n")
            out.flush()
        except BrokenPipeError:
            return 0
    return 0


# ---------------------------------------------------------------- self-test

def _frame(hexstr):
    return decode_frame(bytes.fromhex(hexstr))


def _check(cond, what):
    if not cond:
        raise AssertionError(what)


def _xor(b):
    x = 0
    for c in b:
        x ^= c
    return x


SECTION13 = {
    # name: frame as printed in section 13 (5 preambles)
    "c0_short_p0_pri": "FF FF FF FF FF 02 80 00 00 82",
    "c0_short_p0_sec": "FF FF FF FF FF 02 00 00 00 02",
    "c0_short_p5_pri": "FF FF FF FF FF 02 85 00 00 87",
    "c0_reply_h7": "FF FF FF FF FF 06 80 00 18 00 00 FE 26 06 05 07 01 02 18 00 12 34 56 05 04 00 01 00 00 26 00 26 01 28",
    "c0_reply_h5": "FF FF FF FF FF 06 80 00 0E 00 00 FE 26 06 05 05 01 02 03 00 12 34 56 26",
    "c1_req": "FF FF FF FF FF 82 A6 06 12 34 56 01 00 53",
    "c1_reply": "FF FF FF FF FF 86 A6 06 12 34 56 01 07 00 00 06 41 48 00 00 5F",
    "c3_reply": "FF FF FF FF FF 86 A6 06 12 34 56 03 1A 00 00 41 40 00 00 06 42 48 00 00 21 42 91 00 00 FA 7F A0 00 00 FA 7F A0 00 00 B0",
    "c9_req": "FF FF FF FF FF 82 A6 06 12 34 56 09 02 00 F5 AC",
    "c9_reply": "FF FF FF FF FF 86 A6 06 12 34 56 09 17 00 00 00 00 41 06 42 48 00 00 C0 F5 00 27 41 40 00 00 C0 52 65 C0 00 21",
    "c11_bcast": "FF FF FF FF FF 82 80 00 00 00 00 0B 06 41 4B 71 C3 18 20 8F",
    "c13_reply": "FF FF FF FF FF 86 A6 06 12 34 56 0D 17 00 00 41 4B 71 C3 18 20 08 F2 4C 15 28 06 14 51 20 41 53 50 15 0B 7D 05",
    "c6_req": "FF FF FF FF FF 82 A6 06 12 34 56 06 02 03 00 55",
    "c38_req": "FF FF FF FF FF 82 A6 06 12 34 56 26 02 00 01 77",
    "c35_err": "FF FF FF FF FF 86 A6 06 12 34 56 23 02 09 40 3E",
    "c200_rc64": "FF FF FF FF FF 86 A6 06 12 34 56 C8 02 40 00 DC",
    "comm_err": "FF FF FF FF FF 86 A6 06 12 34 56 01 02 88 00 DD",
    "c31_req": "FF FF FF FF FF 82 A6 06 12 34 56 1F 02 04 00 4B",
    "c31_reply": "FF FF FF FF FF 86 A6 06 12 34 56 1F 05 00 00 04 00 AA E2",
    "c31_rc64": "FF FF FF FF FF 86 A6 06 12 34 56 1F 04 40 00 04 00 09",
    "c103_req": "FF FF FF FF FF 82 A6 06 12 34 56 67 09 00 00 00 7D 00 00 1D 4C 00 10",
    "c108_req": "FF FF FF FF FF 82 A6 06 12 34 56 6C 03 00 09 00 34",
    "c109_req": "FF FF FF FF FF 82 A6 06 12 34 56 6D 02 01 00 3C",
    "back_c1": "FF FF FF FF FF 81 66 06 12 34 56 01 07 00 00 06 41 48 00 00 98",
}

# HART-IP messages of section 13 that carry a token-passing PDU (ID 3):
# the body after the 8-byte header is a frame without preambles.
SECTION13_HARTIP_TP = {
    "hip_tp_req": "01 00 03 00 00 02 00 0D 02 80 00 00 82",
    "hip_tp_resp": "01 01 03 00 00 02 00 25 06 80 00 18 00 00 FE 26 06 05 07 01 02 18 00 12 34 56 05 04 00 01 00 00 26 00 26 01 28",
}

LONG_ADDR = {
    "type": "long", "master": "primary", "burst": False,
    "unique_id": "2606123456", "expanded_device_type": 0x2606,
    "device_id": "123456", "broadcast": False,
}

REQUIRED_KEYS = {"preambles", "delimiter", "frame_type", "address", "expansion",
                 "command", "byte_count", "data", "checksum_ok", "trailing"}
REPLY_KEYS = {"response_code", "device_status", "communication_error"}
OPTIONAL_KEYS = {"command_byte", "decoded"}


def _shape_ok(o):
    """Structural invariants of a successful decode."""
    keys = set(o)
    _check(REQUIRED_KEYS <= keys, "missing keys %r" % (REQUIRED_KEYS - keys))
    allowed = REQUIRED_KEYS | REPLY_KEYS | OPTIONAL_KEYS
    _check(keys <= allowed, "unexpected keys %r" % (keys - allowed))
    if o["frame_type"] == "STX":
        _check(not (keys & REPLY_KEYS), "STX has reply keys")
    else:
        _check(REPLY_KEYS <= keys, "ACK/BACK lacks reply keys")
    a = o["address"]
    if a["type"] == "short":
        _check(set(a) == {"type", "master", "burst", "polling_address"}, "short addr keys")
    else:
        _check(set(a) == {"type", "master", "burst", "unique_id",
                          "expanded_device_type", "device_id", "broadcast"}, "long addr keys")
        _check(len(a["unique_id"]) == 10 and a["unique_id"] == a["unique_id"].upper(), "uid")
        _check(len(a["device_id"]) == 6, "device_id")


def selftest():
    # 0. every section-13 frame: recompute the check byte independently
    for name, h in SECTION13.items():
        b = bytes.fromhex(h)
        body = b[5:]
        _check(b[:5] == b"\xff" * 5, name + ": preamble")
        _check(_xor(body[:-1]) == body[-1], name + ": check byte in reference is wrong")
        _check(_xor(body) == 0, name + ": XOR incl. check byte must be 0")
        o = _frame(h)
        _shape_ok(o)
        _check(o["preambles"] == 5, name + ": preambles")
        _check(o["checksum_ok"] is True, name + ": checksum_ok")
        _check(o["trailing"] == "", name + ": trailing")
        _check(o["expansion"] == "", name + ": expansion")
        json.dumps(o, allow_nan=False)

    # 1. short-address cmd 0 requests
    o = _frame(SECTION13["c0_short_p0_pri"])
    _check(o["frame_type"] == "STX" and o["delimiter"] == 0x02, "c0 delim")
    _check(o["address"] == {"type": "short", "master": "primary", "burst": False,
                            "polling_address": 0}, "c0 pri addr")
    _check(o["command"] == 0 and o["byte_count"] == 0 and o["data"] == "", "c0 cmd")
    _check("decoded" not in o and "command_byte" not in o, "c0 extras")
    o = _frame(SECTION13["c0_short_p0_sec"])
    _check(o["address"]["master"] == "secondary" and o["address"]["polling_address"] == 0, "c0 sec")
    o = _frame(SECTION13["c0_short_p5_pri"])
    _check(o["address"]["master"] == "primary" and o["address"]["polling_address"] == 5, "c0 p5")

    # 2. cmd 0 reply, HART 7
    o = _frame(SECTION13["c0_reply_h7"])
    _check(o["frame_type"] == "ACK" and o["byte_count"] == 24, "h7 frame")
    _check(o["response_code"] == 0 and o["device_status"] == 0, "h7 status")
    _check(o["communication_error"] is False, "h7 comm")
    _check(o["data"] == "FE26060507010218001234560504000100002600" "2601", "h7 data")
    _check(o["decoded"] == {
        "expanded_device_type": 0x2606, "min_request_preambles": 5,
        "universal_revision": 7, "device_revision": 1, "software_revision": 2,
        "hardware_revision": 3, "physical_signaling": 0, "flags": 0,
        "device_id": "123456", "min_response_preambles": 5,
        "max_device_variables": 4, "config_change_counter": 1,
        "extended_status": 0, "manufacturer_id": 0x26,
        "private_label_distributor": 0x26, "device_profile": 1,
    }, "h7 decoded %r" % o["decoded"])

    # 3. cmd 0 reply, HART 5 form (12 bytes)
    o = _frame(SECTION13["c0_reply_h5"])
    _check(o["byte_count"] == 14, "h5 bc")
    _check(o["decoded"] == {
        "expanded_device_type": 0x2606, "min_request_preambles": 5,
        "universal_revision": 5, "device_revision": 1, "software_revision": 2,
        "hardware_revision": 0, "physical_signaling": 3, "flags": 0,
        "device_id": "123456", "manufacturer_id": 0x26, "device_type": 0x06,
    }, "h5 decoded %r" % o["decoded"])

    # 4. cmd 1 request / reply, long address
    o = _frame(SECTION13["c1_req"])
    _check(o["delimiter"] == 0x82 and o["address"] == LONG_ADDR, "c1 req addr %r" % o["address"])
    _check(o["command"] == 1 and "decoded" not in o, "c1 req")
    o = _frame(SECTION13["c1_reply"])
    _check(o["delimiter"] == 0x86 and o["address"] == LONG_ADDR, "c1 reply addr")
    _check(o["decoded"] == {"pv_units": 6, "pv": 12.5}, "c1 decoded")

    # 5. cmd 3 with NaN -> null
    o = _frame(SECTION13["c3_reply"])
    _check(o["decoded"] == {
        "loop_current": 12.0,
        "variables": [
            {"units": 6, "value": 50.0},
            {"units": 33, "value": 72.5},
            {"units": 250, "value": None},
            {"units": 250, "value": None},
        ]}, "c3 decoded %r" % o["decoded"])
    _check('"value": null' in json.dumps(o, allow_nan=False), "c3 null in JSON")

    # 6. cmd 9 request / reply
    o = _frame(SECTION13["c9_req"])
    _check(o["decoded"] == {"slots": [0, 245]}, "c9 req")
    o = _frame(SECTION13["c9_reply"])
    _check(o["decoded"] == {
        "extended_status": 0,
        "slots": [
            {"code": 0, "classification": 65, "units": 6, "value": 50.0, "status": 0xC0},
            {"code": 245, "classification": 0, "units": 39, "value": 12.0, "status": 0xC0},
        ],
        "timestamp": 0x5265C000,
    }, "c9 decoded %r" % o["decoded"])
    _check(0x5265C000 == 12 * 3600 * 1000 * 32, "12:00:00 in 1/32 ms")

    # 7. cmd 11 broadcast request with tag
    o = _frame(SECTION13["c11_bcast"])
    _check(o["address"] == {"type": "long", "master": "primary", "burst": False,
                            "unique_id": "0000000000", "expanded_device_type": 0,
                            "device_id": "000000", "broadcast": True}, "c11 addr")
    _check(o["decoded"] == {"tag": "PT-101"}, "c11 tag %r" % o.get("decoded"))

    # 8. cmd 13 reply
    o = _frame(SECTION13["c13_reply"])
    _check(o["decoded"] == {"tag": "PT-101", "descriptor": "BOILER FEED PUMP",
                            "date": "2025-11-21"}, "c13 %r" % o["decoded"])

    # 9. cmd 6 and cmd 38 requests
    o = _frame(SECTION13["c6_req"])
    _check(o["decoded"] == {"polling_address": 3, "loop_current_mode": 0}, "c6")
    o = _frame(SECTION13["c38_req"])
    _check(o["command"] == 38 and o["decoded"] == {"config_change_counter": 1}, "c38")

    # 10. error replies (no data -> no decoded)
    o = _frame(SECTION13["c35_err"])
    _check((o["command"], o["response_code"], o["device_status"]) == (35, 9, 0x40), "c35")
    _check(o["communication_error"] is False and o["data"] == "", "c35 data")
    o = _frame(SECTION13["c200_rc64"])
    _check((o["command"], o["response_code"]) == (200, 64) and "decoded" not in o, "c200")

    # 11. communication error 0x88
    o = _frame(SECTION13["comm_err"])
    _check(o["response_code"] == 0x88 and o["communication_error"] is True, "comm err")
    _check(o["command"] == 1 and "decoded" not in o and o["data"] == "", "comm err body")

    # 12. cmd 31 -> extended 0x0400 = 1024
    o = _frame(SECTION13["c31_req"])
    _check(o["command"] == 1024 and o["command_byte"] == 31, "c31 req cmd")
    _check(o["byte_count"] == 2 and o["data"] == "", "c31 req data")
    o = _frame(SECTION13["c31_reply"])
    _check(o["command"] == 1024 and o["command_byte"] == 31 and o["data"] == "AA", "c31 reply")
    _check(o["byte_count"] == 5 and o["response_code"] == 0, "c31 reply bc")
    o = _frame(SECTION13["c31_rc64"])
    _check(o["command"] == 1024 and o["response_code"] == 64 and o["data"] == "", "c31 rc64")

    # 13. burst commands (no decoding defined) and BACK
    o = _frame(SECTION13["c103_req"])
    _check(o["command"] == 103 and o["data"] == "0000007D00001D4C00" and "decoded" not in o,
           "c103")
    o = _frame(SECTION13["c108_req"])
    _check(o["command"] == 108 and o["data"] == "000900", "c108")
    o = _frame(SECTION13["c109_req"])
    _check(o["command"] == 109 and o["data"] == "0100", "c109")
    o = _frame(SECTION13["back_c1"])
    _check(o["frame_type"] == "BACK" and o["delimiter"] == 0x81, "back type")
    _check(o["address"]["master"] == "secondary" and o["address"]["burst"] is True, "back addr")
    _check(o["address"]["unique_id"] == "2606123456", "back uid")
    _check(o["decoded"] == {"pv_units": 6, "pv": 12.5}, "back decoded")

    # 14. preamble counts: 4, 1, 0 (HART-IP style), 20
    base = SECTION13["c1_reply"].replace("FF ", "")
    for k in (0, 1, 2, 4, 20):
        o = _frame("FF " * k + base)
        _check(o["preambles"] == k and o["checksum_ok"] and o["decoded"]["pv"] == 12.5,
               "preambles %d" % k)
    for name, h in SECTION13_HARTIP_TP.items():
        b = bytes.fromhex(h)
        _check(u16(b, 6) == len(b), name + ": HART-IP byte count")
        o = decode_frame(b[8:])
        _check(o["preambles"] == 0 and o["checksum_ok"], name)
    o = decode_frame(bytes.fromhex(SECTION13_HARTIP_TP["hip_tp_resp"])[8:])
    _check(o["decoded"]["expanded_device_type"] == 0x2606, "hip resp decoded")

    # 15. text-form tolerance, trailing bytes, bad checksum, errors
    o = decode_line("ff:ff:86:a6:06:12:34:56:01:07:00:00:06:41:48:00:00:5f:de:ad\r\n")
    _check(o["preambles"] == 2 and o["trailing"] == "DEAD" and o["checksum_ok"], "colons/trailing")
    o = decode_line(SECTION13["c1_reply"][:-2] + "5E")
    _check(o["checksum_ok"] is False, "bad checksum")
    _check(decode_line(SECTION13["c1_reply"][:-3]) == {"error": "truncated"}, "truncated check")
    _check(decode_line(SECTION13["c1_reply"][:-6]) == {"error": "truncated"}, "truncated data")
    _check(decode_line("FF FF FF 86 A6 06") == {"error": "truncated"}, "truncated header")
    _check("error" in decode_line("FF FF 03 80 00 00 83"), "frame type 3")
    _check("error" in decode_line("FF FF 86 A6 06 12 34 56 01 01 00 DB"), "ACK bc 1")
    _check("error" in decode_line("FF FF FF"), "only preamble")
    _check("error" in decode_line(""), "empty")
    _check("error" in decode_line("zz"), "non-hex")
    _check("error" in decode_line("FFF"), "odd")
    o = decode_line("02 80 00 00 82")
    _check(o["preambles"] == 0 and o["command"] == 0, "no preamble")
    # expansion bytes (delimiter bits 6-5 = 2)
    f = bytes([0x42, 0x80, 0x12, 0x34, 0x00, 0x00])
    f = f + bytes([_xor(f)])
    o = decode_frame(f)
    _check(o["expansion"] == "1234" and o["checksum_ok"] and o["command"] == 0, "expansion")
    # cmd 31 with too few data bytes keeps command 31
    f = bytes([0x06, 0x80, 0x1F, 0x02, 0x88, 0x00])
    o = decode_frame(f + bytes([_xor(f)]))
    _check(o["command"] == 31 and o["command_byte"] == 31 and o["data"] == "", "c31 short")

    # 16. packed ASCII examples from section 10.1
    _check(packed_ascii(bytes.fromhex("0420C41461C8")) == "ABCDEFGH", "pack1")
    _check(packed_ascii(bytes.fromhex("820820820820")) == "", "pack spaces")
    _check(packed_ascii(bytes.fromhex("FFFFFFFFFFFF")) == "????????", "pack ?")

    # 17. fuzz: 10 000 random byte strings must never raise
    rng = random.Random(0x4A27)
    ok = err = 0
    valid = [bytes.fromhex(h) for h in SECTION13.values()]
    for i in range(10000):
        kind = i % 4
        if kind == 0:  # uniformly random bytes
            b = bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 80)))
        elif kind == 1:  # random bytes behind a plausible preamble + delimiter
            b = (b"\xff" * rng.randrange(0, 6)
                 + bytes([rng.choice((1, 2, 6, 0x81, 0x82, 0x86, 0xE6, 0x09))])
                 + bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 300))))
        elif kind == 2:  # mutated / cut valid frames
            b = bytearray(rng.choice(valid))
            for _ in range(rng.randrange(1, 4)):
                b[rng.randrange(len(b))] = rng.getrandbits(8)
            b = bytes(b[:rng.randrange(0, len(b) + 3)]) + bytes(rng.getrandbits(8) for _ in range(rng.randrange(0, 3)))
        else:  # random text, mostly hex-ish
            alphabet = "0123456789abcdefABCDEF :\tFFxg-\x00\xff"
            b = None
            line = "".join(rng.choice(alphabet) for _ in range(rng.randrange(0, 60)))
        if b is not None:
            line = " ".join("%02x" % c for c in b)
        o = decode_line(line)
        s = to_json(o)
        json.loads(s)
        if "error" in o:
            _check(set(o) == {"error"}, "error object shape")
            _check(not o["error"].startswith("internal"), "internal error on %r" % line)
            err += 1
        else:
            _shape_ok(o)
            ok += 1
    print("selftest: %d section-13 frames OK; fuzz 10000 inputs (%d decoded, %d errors), "
          "no exceptions" % (len(SECTION13) + len(SECTION13_HARTIP_TP), ok, err))
    return 0


def main(argv):
    if len(argv) > 1 and argv[1] == "--selftest":
        return selftest()
    return main_stream()


if __name__ == "__main__":
    sys.exit(main(sys.argv))

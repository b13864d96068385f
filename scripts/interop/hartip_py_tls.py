#!/usr/bin/env python3
"""Interop check: hartip-py's HART-IP version 2 client (TLS 1.2 with a pre-shared key,
over TCP) against hartkit's secure server, in both orders hartip-py offers: the
STARTTLS order of HCF_SPEC-085 (session initiate in the clear, then the handshake; its
default) and TLS first. hartip-py is GPL: run as a separate process only.

    python hartip_py_tls.py --host 127.0.0.1 --port PORT --identity ID --key HEX

Prints one JSON object per step; exit 0 when both orders read command 0 at polling
address 0 (the I/O system) and command 1 from the device at polling address 1 with
response code 0. PSK callbacks in Python's ssl module need Python 3.13; on an older
Python the script says so and exits 3.
"""

import argparse
import json
import sys

if sys.version_info < (3, 13):
    print("hartip_py_tls: TLS-PSK needs Python 3.13 (ssl PSK callbacks)", file=sys.stderr)
    sys.exit(3)

from hartip import HARTIPClient, parse_cmd0  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--identity", required=True)
    ap.add_argument("--key", required=True, help="the key as hex")
    a = ap.parse_args()
    ok = True
    for starttls in (True, False):
        step = {"step": "tls", "order": "starttls" if starttls else "tls-first"}
        try:
            c = HARTIPClient(
                a.host,
                a.port,
                protocol="tcp",
                version=2,
                psk_identity=a.identity,
                psk_key=bytes.fromhex(a.key),
                starttls=starttls,
                timeout=5,
            )
            c.connect()
            r0 = c.send_command(0, address=0)
            info = parse_cmd0(r0.payload)
            r1 = c.send_command(1, address=1)
            c.close()
            step.update(
                cmd0_rc=r0.response_code,
                device_profile=info.device_profile,
                cmd1_rc=r1.response_code,
                pv_units=r1.payload[0] if r1.payload else None,
            )
            ok = ok and r0.response_code == 0 and info.device_profile == 68 and r1.response_code == 0
        except Exception as e:  # the failure is the finding
            step["error"] = f"{type(e).__name__}: {e}"
            ok = False
        print(json.dumps(step), flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

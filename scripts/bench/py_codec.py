#!/usr/bin/env python3
"""Frames parsed and decoded per second from Python, by one library per process (run
by scripts/bench-python; the libraries never share a process).

    python py_codec.py hartkit|hart-protocol [SECONDS]

Two measurements, each library through its own API:

* per call: the bytes of one reply (delimiter through check byte) to its fields
  decoded, for command 3 (loop current, dynamic variables) and command 0 (identity).
  hartkit: Frame.parse(pdu).decoded. hart-protocol (yaq, LGPL-3.0): its internal
  hart_protocol._parsing.parse(pdu without the check byte), the fastest thing it has
  (its Unpacker calls it after checking the check byte).
* stream: 20 000 command 3 replies with 5 preambles each, as a serial port or capture
  delivers them, to decoded messages. hartkit: Deframer().feed(chunk) and .decoded on
  each frame, in 4 KiB chunks. hart-protocol: its public Unpacker over the same bytes.

Prints one JSON object.
"""

import json
import sys
import time

# Command 3 reply (long address) and command 0 reply (HART 7 identity), both built by
# hand from the layouts in shared/docs/hart-reference.md.
CMD3 = bytes.fromhex(
    "86A606BC614E031A0000" "40800000" "0C" "42F6E979" "20" "41BC0000" "20" "41C00000" "20" "41C80000"
)
CMD0 = bytes.fromhex("82A606BC614E0018" "0000" "FE2606050707030A00BC614E0508000300000000F0F0")


def with_checksum(pdu: bytes) -> bytes:
    x = 0
    for b in pdu:
        x ^= b
    return pdu + bytes([x])


# Fix the byte counts (data + 2 status bytes) and append the check bytes.
def frame(head: bytes, body: bytes) -> bytes:
    return with_checksum(head + bytes([len(body)]) + body)


CMD3 = frame(CMD3[:7], CMD3[8:])
CMD0 = frame(bytes.fromhex("86A606BC614E00"), bytes.fromhex("0000FE2606050707030A00BC614E0508000300000000F0F0"))


def main() -> None:
    lib = sys.argv[1]
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 3.0
    if lib == "hartkit":
        import hartkit

        def decode(pdu: bytes):
            return hartkit.Frame.parse(pdu).decoded

        check = decode(CMD3)
        assert abs(check["variables"][0]["value"] - 123.456) < 1e-3, check
    elif lib == "hart-protocol":
        from hart_protocol._parsing import parse

        def decode(pdu: bytes):
            return parse(pdu[:-1])

        check = decode(CMD3)
        assert abs(check["primary_variable"] - 123.456) < 1e-3, check
    else:
        raise SystemExit(f"py_codec.py: unknown library {lib!r}")
    results = {}
    stream = (b"\xff" * 5 + CMD3) * 20000
    if lib == "hartkit":
        def run_stream() -> int:
            d = hartkit.Deframer()
            n = 0
            for i in range(0, len(stream), 4096):
                for f in d.feed(stream[i : i + 4096]):
                    f.decoded
                    n += 1
            return n
    else:
        import io
        from hart_protocol import Unpacker

        class Port(io.BytesIO):
            # What Unpacker reads from (a serial port's in_waiting).
            @property
            def in_waiting(self) -> int:
                return len(self.getbuffer()) - self.tell()

        def run_stream() -> int:
            return sum(1 for _ in Unpacker(Port(stream)))
    t0 = time.perf_counter()
    n = run_stream()
    assert n == 20000, n
    results["stream of command 3 replies"] = n / (time.perf_counter() - t0)
    for name, pdu in (("command 3 reply", CMD3), ("command 0 reply", CMD0)):
        n = 0
        t0 = time.perf_counter()
        end = t0 + seconds
        while True:
            for _ in range(1000):
                decode(pdu)
            n += 1000
            if time.perf_counter() >= end:
                break
        results[name] = n / (time.perf_counter() - t0)
    print(json.dumps({"library": lib, "frames_per_s": results}))


if __name__ == "__main__":
    main()

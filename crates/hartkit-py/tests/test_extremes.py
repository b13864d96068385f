"""No panic crosses into Python: every public call, given extreme values (integers far
out of range, negative ones, NaN and infinities, huge byte strings, wrong types), either
works or raises an ordinary Python exception that names what is wrong. A Rust panic
would surface as pyo3's PanicException, which derives from BaseException and so is not
caught by ``except Exception``: the test fails on it."""

import math
import random

import pytest

import hartkit
import hartkit.sync

INTS = [0, 1, -1, 63, 64, 255, 256, 65535, 65536, 2**31, 2**63, -(2**63), 10**30]
FLOATS = [0.0, -0.0, 1e-300, -1.0, 1e308, -1e308, math.inf, -math.inf, math.nan]
BYTES = [b"", b"\x00", b"\xff" * 255, b"\xff" * 256, bytes(range(256)) * 40]
EXPECTED = (ValueError, OverflowError, TypeError, hartkit.HartError, KeyError)


def call(f, *args, **kw):
    """Calls f; an ordinary exception is fine, anything else fails the test."""
    try:
        f(*args, **kw)
    except EXPECTED:
        pass


def test_frames_from_extreme_values():
    for address in INTS + ["26F1010002", "zz", "", "26F1010002FF"]:
        for command in INTS:
            for data in BYTES:
                call(hartkit.Frame.request, address, command, data)
                call(hartkit.Frame.reply, address, command, data, response_code=7)
    for preambles in INTS:
        call(hartkit.Frame.request, 1, 0, b"", preambles=preambles)
    for code in INTS:
        call(hartkit.Frame.reply, 1, 3, b"", response_code=code, device_status=code)
    with pytest.raises(ValueError, match="preambles"):
        hartkit.Frame.request(1, 0, b"", preambles=10**12)
    with pytest.raises(ValueError, match="data"):
        hartkit.Frame.request(1, 0, b"\x00" * 300)


def test_decoders_and_tables_from_extreme_values():
    rng = random.Random(7)
    for command in INTS:
        for data in BYTES + [bytes(rng.randrange(256) for _ in range(rng.randrange(60))) for _ in range(20)]:
            call(hartkit.decode_reply, command, data)
            call(hartkit.decode_request, command, data)
        for code in INTS:
            call(hartkit.response_code_name, code, command)
        call(hartkit.unit, command)
    d = hartkit.Deframer()
    for data in BYTES:
        call(d.feed, data)
    for data in BYTES:
        call(hartkit.Frame.parse, data)


def test_encoders_from_extreme_values():
    for command in [0, 1, 6, 17, 34, 35, 40, 44, 59, 103, 107, 109, 512, 65535, -1, 2**40]:
        for value in INTS + FLOATS + ["", "x" * 1000, None, [], {}]:
            for field in ["pv_units", "damping", "upper_range_value", "message", "polling_address",
                          "response_preambles", "burst_message", "update_period", "nonsense"]:
                call(hartkit.encode_request, command, {field: value})
                call(hartkit.encode_reply, command, {field: value})


def test_the_simulation_from_extreme_values():
    for devices in [0, 1, 64, -1, 2**40]:
        call(hartkit.sim.bench, devices=devices, duration=0.5)
    for duration in FLOATS:
        call(hartkit.sim.bench, devices=1, duration=duration)
    for value in FLOATS:
        call(hartkit.sim.bench, devices=1, duration=0.5, ber=value)
        call(hartkit.sim.bench, devices=1, duration=0.5, burst=True, burst_period=value)
        call(hartkit.sim.bench, devices=1, duration=0.2, analog=True, cable_m=value)
    for seed in [0, 2**64 - 1, -1, 2**64]:
        call(hartkit.sim.bench, devices=1, duration=0.5, seed=seed)


def test_a_loop_from_extreme_values():
    with hartkit.sync.connect("sim?virtual") as loop:
        for first, last in [(0, 0), (63, 0), (-1, 5), (0, 256), (2**40, 1)]:
            call(loop.scan, first, last)
        for seconds in FLOATS:
            call(loop.listen, seconds)
        dev = loop.device(poll=1)
        for command in INTS:
            for data in BYTES[:4]:
                call(dev.command, command, data)
        for value in FLOATS:
            call(dev.write_damping, value)
            call(dev.write_range, value, -value)
        for tag in ["", "x" * 100, "\u00e9\u4e2d", "PT-1"]:
            call(dev.write_tag, tag)
            call(dev.write_long_tag, tag)
    for target in ["", "nonsense", "udp://", "serial:/dev/null?baud=-1", "sim:/no/such.toml"]:
        call(hartkit.sync.connect, target)

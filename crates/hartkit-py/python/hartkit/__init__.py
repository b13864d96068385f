"""hartkit: HART field communication for Python.

Frames and commands (``Frame``, ``hartkit.commands``), a HART master on any target the
``hartkit`` command line takes (a modem on a serial port, RS-485, HART-IP, a simulated
plant) with an asyncio API (``connect``) and a blocking one (``hartkit.sync``), and the
network simulation (``hartkit.sim``). The work is done by hartkit's Rust crates; waiting
never holds the GIL.

    import asyncio, hartkit

    async def main():
        async with hartkit.connect("sim") as loop:
            dev = await loop.device(poll=1)
            print(await dev.read_dynamic())

    asyncio.run(main())
"""

from ._native import (
    Deframer,
    DeviceError,
    Frame,
    FrameError,
    HartError,
    NoReplyError,
    TargetError,
    __version__,
    decode_reply,
    decode_request,
    response_code_name,
    unit,
)
from . import commands, sim, wireless
from .commands import encode_reply, encode_request
from ._host import Device, DeviceInfo, Loop, Reply, connect

__all__ = [
    "Deframer",
    "Device",
    "DeviceError",
    "DeviceInfo",
    "Frame",
    "FrameError",
    "HartError",
    "Loop",
    "NoReplyError",
    "Reply",
    "TargetError",
    "__version__",
    "commands",
    "connect",
    "decode_reply",
    "decode_request",
    "encode_reply",
    "encode_request",
    "response_code_name",
    "sim",
    "unit",
    "wireless",
]

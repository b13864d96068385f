"""Simulation from Python: simulated devices behind a HART-IP server, for testing a
host (``serve_hart_ip``), and the network simulation (``bench``)."""

import os
import threading
import tty
from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Tuple, Union

from ._native import Deframer, Frame, SimServer, serve_hart_ip as _serve_hart_ip, sim_bench as _sim_bench
from .commands import Record, encode_reply

__all__ = ["PythonDevice", "SimServer", "bench", "serve_hart_ip"]

#: What a command handler returns: the reply data (response code 0), or
#: (response code, reply data); the data as bytes, or as the reply's fields (a dict or
#: Record with the names ``decode_reply`` gives) for a command hartkit types.
HandlerResult = Union[bytes, Mapping[str, Any], Record, Tuple[int, Union[bytes, Mapping[str, Any], Record]]]


class _Served:
    """A SimServer as a context manager."""

    def __init__(self, server: SimServer):
        self.server = server

    def __getattr__(self, name: str) -> Any:
        return getattr(self.server, name)

    def close(self) -> None:
        self.server.close()

    def __enter__(self) -> "_Served":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def serve_hart_ip(
    profiles: Sequence[str] = ("pressure", "temperature", "valve"),
    address: str = "127.0.0.1:0",
) -> _Served:
    """Serves simulated devices of ``profiles`` (built-in "pressure", "temperature",
    "valve", or profile files) at polling addresses 1, 2, ... behind a HART-IP server
    on ``address`` (port 0: a free one), answering at once, as ``hartkit serve --sim
    --instant`` does. Returns once it listens; ``.target`` ("udp://127.0.0.1:PORT"),
    ``.tcp_target``, ``.port``, ``.close()``; also a context manager. Any HART-IP
    host can talk to it: ``hartkit.connect(server.target)``, the hartkit CLI, or
    another tool."""
    return _Served(_serve_hart_ip(list(profiles), address))


def bench(
    *,
    devices: int = 15,
    duration: float = 60.0,
    secondary: bool = False,
    burst: bool = False,
    burst_period: float = 1.0,
    command: int = 3,
    ber: float = 0.0,
    seed: int = 1,
    analog: bool = False,
    cable_m: float = 0.0,
) -> Dict[str, Any]:
    """Runs ``hartkit sim bench``: a primary master scans ``devices`` devices and polls
    them for ``duration`` virtual seconds (optionally with a secondary master, a burst
    device, a bit error rate, or on the analog loop with ``cable_m`` of cable). Returns
    the dict ``hartkit sim bench --json`` prints: ``transactions``, ``failed``,
    ``retries``, ``collisions``, ``efficiency``, ... The GIL is released while it runs."""
    return _sim_bench(
        devices=devices,
        duration=duration,
        secondary=secondary,
        burst=burst,
        burst_period=burst_period,
        command=command,
        ber=ber,
        seed=seed,
        analog=analog,
        cable_m=cable_m,
    )


class PythonDevice:
    """A field device whose commands are answered by Python callables, on a
    pseudo-terminal that a host opens as its serial port (``hartkit read -p
    serial:PATH``, or ``hartkit.connect(path)``): for testing hosts with exactly the
    replies a test needs.

        def read_pv(data):                       # command 1: units (kPa), value
            return bytes([12]) + struct.pack(">f", 42.0)

        with hartkit.sim.PythonDevice({1: read_pv}) as dev:
            ...  # hartkit read -p dev.path --poll 0 pv

    ``handlers`` maps a command number to a function of the request data returning the
    reply data (response code 0) or (response code, data), the data as bytes or as the
    reply's fields (``{"pv_units": "kPa", "pv": 42.0}``); an exception in it answers
    response code 6 (device-specific command error). Command 0 answers with a HART 7
    identity for ``unique_id`` unless a handler is given for it; other commands answer
    64 (not implemented). The device answers its polling address ``poll`` in short
    frames and its unique ID in long frames; ``device_status`` goes in every reply.
    ``requests`` lists every request it answered, as Frames.

    ``serve_hart_ip()`` puts it behind a HART-IP server as well, for a HART-IP host."""

    def __init__(
        self,
        handlers: Dict[int, Callable[[bytes], HandlerResult]],
        *,
        poll: int = 0,
        unique_id: str = "26F1ABCDEF",
        device_status: int = 0,
    ):
        if len(unique_id) != 10:
            raise ValueError("unique_id: 10 hex digits (expanded device type, device ID)")
        self.handlers = dict(handlers)
        self.poll = poll
        self.unique_id = unique_id.upper()
        self.device_status = device_status
        self.requests: list = []
        self._master, slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="hartkit PythonDevice", daemon=True)
        self._thread.start()

    def _identity(self) -> bytes:
        uid = bytes.fromhex(self.unique_id)
        edt = ((uid[0] & 0x3F) << 8) | uid[1]
        # Byte 0 254, expanded device type, 5 request preambles, HART 7, device rev 1,
        # software 1, hardware 1 / Bell 202, flags 0, device ID, 5 reply preambles, 1
        # device variable, change counter 0, extended status 0, manufacturer 0x00F0,
        # private label 0x00F0, device profile 1 (process automation).
        return (
            bytes([254]) + edt.to_bytes(2, "big") + bytes([5, 7, 1, 1, 0x08, 0]) + uid[2:]
            + bytes([5, 1, 0, 0, 0]) + (0xF0).to_bytes(2, "big") + (0xF0).to_bytes(2, "big") + bytes([1])
        )

    def _mine(self, f: Frame) -> bool:
        if f.frame_type != "STX":
            return False
        if f.polling_address is not None:
            return f.polling_address == self.poll and f.command == 0
        return f.unique_id == self.unique_id

    def _answer(self, f: Frame) -> Frame:
        handler = self.handlers.get(f.command)
        rc, data = 0, b""
        if handler is None and f.command == 0:
            data = self._identity()
        elif handler is None:
            rc = 64
        else:
            try:
                out = handler(f.data)
                rc, data = out if isinstance(out, tuple) else (0, out)
                if not isinstance(data, (bytes, bytearray, memoryview)):
                    data = encode_reply(f.command, data)
            except Exception:  # a test's handler failing is the device's failure
                rc, data = 6, b""
        address: Union[int, str] = f.polling_address if f.polling_address is not None else self.unique_id
        return Frame.reply(
            address,
            f.command,
            bytes(data),
            response_code=rc,
            device_status=self.device_status,
            secondary=f.master == "secondary",
        )

    def _serve(self) -> None:
        d = Deframer()
        while not self._stop.is_set():
            try:
                chunk = os.read(self._master, 4096)
            except OSError:
                return
            if not chunk:
                return
            for f in d.feed(chunk):
                if self._mine(f):
                    self.requests.append(f)
                    os.write(self._master, self._answer(f).to_bytes())

    def serve_hart_ip(self, address: str = "127.0.0.1:0") -> "_Served":
        """Serves this device behind a HART-IP server on ``address`` (port 0: a free
        one), which reaches it through its pseudo-terminal as ``hartkit serve -p
        serial:PATH`` would: at polling address 0 the device answers there itself
        (no I/O system in front), at another address the server is the I/O system at
        0 and the device is found at its own. Returns once the server listens, as
        ``serve_hart_ip`` does; close it before the device."""
        return _Served(
            _serve_hart_ip(
                [],
                address,
                loops=[f"serial:{self.path}"],
                scan_to=self.poll,
                transparent=self.poll == 0,
            )
        )

    def close(self) -> None:
        """Stops answering and closes the pseudo-terminal."""
        self._stop.set()
        for fd in (self._slave, self._master):
            try:
                os.close(fd)
            except OSError:
                pass

    def __enter__(self) -> "PythonDevice":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

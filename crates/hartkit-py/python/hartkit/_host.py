"""The asyncio host: ``connect``, ``Loop``, ``Device``."""

import asyncio
from dataclasses import dataclass, field
from typing import Any, AsyncIterator, Dict, List, Optional, Tuple

from . import _native
from .commands import Record, by_number
from ._native import Frame


@dataclass(frozen=True)
class DeviceInfo:
    """A device found on the loop: its identity (command 0) and tags."""

    unique_id: str
    polling_address: Optional[int]
    tag: Optional[str]
    descriptor: Optional[str]
    long_tag: Optional[str]
    universal_revision: int
    manufacturer_id: int
    expanded_device_type: int
    device_id: str
    io_card: Optional[int]
    channel: Optional[int]
    identity: Record = field(compare=False)

    @property
    def revision(self) -> int:
        """The HART revision; the same as ``universal_revision`` (the name every other
        view uses), kept for code written before."""
        return self.universal_revision

    @property
    def io_channel(self) -> Optional[Tuple[int, int]]:
        """``(io_card, channel)`` behind an I/O system, ``None`` on a loop of its own;
        kept for code written before."""
        if self.io_card is None or self.channel is None:
            return None
        return (self.io_card, self.channel)

    @classmethod
    def _from(cls, d: Dict[str, Any]) -> "DeviceInfo":
        return cls(
            unique_id=d["unique_id"],
            polling_address=d["polling_address"],
            tag=d["tag"],
            descriptor=d["descriptor"],
            long_tag=d["long_tag"],
            universal_revision=d["universal_revision"],
            manufacturer_id=d["manufacturer_id"],
            expanded_device_type=d["expanded_device_type"],
            device_id=d["device_id"],
            io_card=d.get("io_card"),
            channel=d.get("channel"),
            identity=Record(d["identity"]),
        )


@dataclass(frozen=True, repr=False)
class Reply:
    """A device's reply to a command. The decoded fields are attributes of the reply
    itself (``reply.variables[0].value``), and of ``reply.decoded``."""

    command: int
    response_code: int
    response_code_name: Optional[str]
    device_status: int
    device_status_set: List[str]
    data: bytes
    frame: Frame
    decoded: Optional[Record]
    decode_error: Optional[str]
    additional_status: Optional[bytes]

    @classmethod
    def _from(cls, d: Dict[str, Any]) -> "Reply":
        decoded = d.get("decoded")
        extra = d.get("additional_status")
        typed = by_number(d["command"])
        return cls(
            command=d["command"],
            response_code=d["response_code"],
            response_code_name=d["response_code_name"],
            device_status=d["device_status"],
            device_status_set=list(d["device_status_set"]),
            data=bytes.fromhex(d["data"]),
            frame=Frame.parse(bytes.fromhex(d["pdu"])),
            decoded=Record(decoded) if isinstance(decoded, dict) and typed else None,
            decode_error=d.get("decode_error"),
            additional_status=bytes.fromhex(extra) if extra else None,
        )

    def __repr__(self) -> str:
        status = f" status {self.device_status_set}" if self.device_status_set else ""
        fields = f": {self.decoded}" if self.decoded is not None else f": data {self.data.hex().upper()}"
        return f"<Reply command {self.command} rc {self.response_code} ({self.response_code_name}){status}{fields}>"

    def __getattr__(self, name: str) -> Any:
        # The decoded fields, as attributes of the reply itself.
        decoded = object.__getattribute__(self, "decoded")
        if decoded is not None and name in decoded:
            return getattr(decoded, name)
        raise AttributeError(name)


class _DeviceOps:
    """Every operation on a device, written once: each returns ``self._run(...)``, a
    coroutine for the asyncio ``Device``, the result itself for ``hartkit.sync``'s."""

    def __init__(self, loop: Any, info: DeviceInfo):
        self.loop = loop
        self.info = info

    def _run(self, op: str, args: tuple, conv: Any) -> Any:  # pragma: no cover
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"<Device {self.info.unique_id} tag {self.info.tag!r} poll {self.info.polling_address}>"

    def command(self, number: int, data: bytes = b""):
        """Sends command ``number`` with ``data``; the reply decoded. Raises
        DeviceError (``response_code``) when the device refuses it, NoReplyError when
        it does not answer."""
        return self._run("command", (self.info.unique_id, number, bytes(data)), Reply._from)

    def request(self, command: Any, fields: Any = None, **kw: Any):
        """Sends a typed command built from its fields: ``command`` is a class of
        ``hartkit.commands`` or a number, the fields a Record, a dict or keywords
        (``await dev.request(commands.WritePvUnits, pv_units="kPa")``); the reply
        decoded, as ``command`` gives it."""
        cls = command if isinstance(command, type) else by_number(int(command))
        if cls is None:
            raise _native.FrameError(
                f"hartkit has no layout for command {command}: send its data with command()"
            )
        return self.command(cls.number, cls.encode_request(fields, **kw))

    def read_pv(self):
        """Command 1: the primary variable and its units."""
        return self.command(1)

    def read_dynamic(self):
        """Command 3: loop current and the dynamic variables (PV, SV, TV, QV)."""
        return self.command(3)

    def read_variables(self, *codes: int):
        """Command 9: device variables with status (up to 8 codes)."""
        return self.request(9, slots=list(codes))

    def write(self, what: str, *values: Any):
        """Writes as ``hartkit write WHAT VALUES...`` does (tag, long-tag,
        descriptor, message, date, range, units, damping, polling-address,
        fixed-current, preambles) and reads the value back: (reply, read-back)."""
        return self._write(what, values, lambda d: (Reply._from(d["reply"]), Reply._from(d["read_back"])))

    def _write(self, what: str, values: Any, conv: Any):
        return self._run("write", (self.info.unique_id, what, [str(v) for v in values]), conv)

    def write_tag(self, tag: str):
        """Command 18 with the new tag (descriptor and date kept); the read-back
        (command 13)."""
        return self._write("tag", (tag,), _read_back)

    def write_long_tag(self, long_tag: str):
        """Command 22; the read-back (command 20)."""
        return self._write("long-tag", (long_tag,), _read_back)

    def write_damping(self, seconds: float):
        """Command 34; the read-back (command 15)."""
        return self._write("damping", (seconds,), _read_back)

    def write_range(self, upper: float, lower: float, units: Optional[int] = None):
        """Command 35 (units kept unless given); the read-back (command 15)."""
        return self._write("range", (upper, lower) + ((units,) if units is not None else ()), _read_back)


def _read_back(d: Dict[str, Any]) -> Reply:
    return Reply._from(d["read_back"])


class _LoopOps:
    """Every operation on a loop, written once (see ``_DeviceOps``)."""

    _device_class: Any = None

    def __init__(self, native: "_native.NativeLoop"):
        self._native = native

    def _run(self, op: str, args: tuple, conv: Any) -> Any:  # pragma: no cover
        raise NotImplementedError

    @property
    def description(self) -> str:
        """What is connected ("simulated plant of 4 device(s)")."""
        return self._native.description

    def scan(self, first: int = 0, last: int = 15):
        """Polling addresses ``first..=last`` with command 0 (and tags): the devices
        found."""
        return self._run("scan", (first, last), lambda ds: [DeviceInfo._from(d) for d in ds])

    def device(
        self,
        poll: Optional[int] = None,
        *,
        tag: Optional[str] = None,
        long_tag: Optional[str] = None,
        unique_id: Optional[str] = None,
    ):
        """The device at a polling address, or with a tag, long tag or unique ID."""
        given = [
            (k, v)
            for k, v in (("poll", poll), ("tag", tag), ("long_tag", long_tag), ("unique_id", unique_id))
            if v is not None
        ]
        if len(given) != 1:
            raise ValueError("say which device: poll=N, tag=T, long_tag=T or unique_id=HEX (one of them)")
        kind, value = given[0]
        return self._run("resolve", (kind, value), lambda d: self._device_class(self, DeviceInfo._from(d)))

    def listen(self, seconds: float):
        """Listens for ``seconds``: the burst frames heard."""
        return self._run("listen", (seconds,), lambda hs: [Frame.parse(bytes.fromhex(h)) for h in hs])

    def _close(self) -> None:
        self._native.close()


class Device(_DeviceOps):
    """A device on a loop (asyncio): every method is a coroutine."""

    async def _run(self, op: str, args: tuple, conv: Any) -> Any:
        return conv(await self.loop._native.call(op, args))


class Loop(_LoopOps):
    """A connection to a loop, a HART-IP server or a simulated plant (asyncio)."""

    _device_class = Device

    async def _run(self, op: str, args: tuple, conv: Any) -> Any:
        return conv(await self._native.call(op, args))

    async def bursts(self, every: float = 0.5) -> AsyncIterator[Frame]:
        """Burst frames as they come (listening ``every`` seconds at a time), for
        ``async for``."""
        while True:
            for f in await self.listen(every):
                yield f

    async def close(self) -> None:
        """Closes the connection."""
        self._close()

    async def __aenter__(self) -> "Loop":
        return self

    async def __aexit__(self, *exc: Any) -> None:
        await self.close()


class _Connecting:
    """``await connect(...)`` or ``async with connect(...) as loop``."""

    def __init__(self, target: str, secondary: bool, psk: Optional[str]):
        self._args = (target, secondary, psk)
        self._loop: Optional[Loop] = None

    async def _open(self) -> Loop:
        target, secondary, psk = self._args
        native = await asyncio.get_running_loop().run_in_executor(
            None, lambda: _native.open_loop(target, secondary=secondary, psk=psk)
        )
        return Loop(native)

    def __await__(self):
        return self._open().__await__()

    async def __aenter__(self) -> Loop:
        self._loop = await self._open()
        return self._loop

    async def __aexit__(self, *exc: Any) -> None:
        if self._loop is not None:
            await self._loop.close()


def connect(target: str, *, secondary: bool = False, psk: Optional[str] = None) -> _Connecting:
    """Connects to ``target``: anything ``hartkit --port`` takes (``/dev/ttyUSB0``,
    ``serial:PATH?baud=1200``, ``rs485:PATH``, ``udp://HOST[:PORT]``,
    ``tcp://HOST[:PORT]``, ``tls://...`` and ``dtls://...`` with ``psk``
    "IDENTITY:HEXKEY", ``sim``, ``sim:PLANT.toml``, ``sim?virtual``). As the primary
    master, or the secondary. Use ``async with connect(...) as loop`` or ``loop = await
    connect(...)``. Raises TargetError when the target cannot be opened."""
    return _Connecting(target, secondary, psk)

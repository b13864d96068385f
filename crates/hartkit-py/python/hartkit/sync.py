"""The blocking host, for scripts and notebooks: the same API as ``hartkit.connect``
without ``await``. It needs no event loop (so it works in Jupyter, where one is already
running); each call waits with the GIL released.

    import hartkit.sync
    with hartkit.sync.connect("sim") as loop:
        dev = loop.device(poll=1)
        print(dev.read_dynamic().variables[0].value)
"""

from typing import Any, Iterator, Optional

from . import _native
from ._host import DeviceInfo, Reply, _DeviceOps, _LoopOps
from ._native import Frame

__all__ = ["Device", "DeviceInfo", "Loop", "Reply", "connect"]


class Device(_DeviceOps):
    """A device on a loop; every method blocks until the answer is in."""

    def _run(self, op: str, args: tuple, conv: Any) -> Any:
        return conv(self.loop._native.call_blocking(op, args))


class Loop(_LoopOps):
    """A connection to a loop, a HART-IP server or a simulated plant (blocking)."""

    _device_class = Device

    def _run(self, op: str, args: tuple, conv: Any) -> Any:
        return conv(self._native.call_blocking(op, args))

    def bursts(self, every: float = 0.5) -> Iterator[Frame]:
        """Burst frames as they come (listening ``every`` seconds at a time)."""
        while True:
            yield from self.listen(every)

    def close(self) -> None:
        """Closes the connection."""
        self._close()

    def __enter__(self) -> "Loop":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def connect(target: str, *, secondary: bool = False, psk: Optional[str] = None) -> Loop:
    """Connects to ``target`` (anything ``hartkit --port`` takes; see
    ``hartkit.connect``). Raises TargetError when it cannot be opened."""
    return Loop(_native.open_loop(target, secondary=secondary, psk=psk))

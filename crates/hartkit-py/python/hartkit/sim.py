"""Simulation from Python: simulated devices behind a HART-IP server, for testing a
host (``serve_hart_ip``), and the network simulation (``bench``)."""

from typing import Any, Dict, Sequence

from ._native import SimServer, serve_hart_ip as _serve_hart_ip, sim_bench as _sim_bench

__all__ = ["SimServer", "bench", "serve_hart_ip"]


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

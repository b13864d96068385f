"""The network simulation from Python."""

from typing import Any, Dict

from ._native import sim_bench as _sim_bench

__all__ = ["bench"]


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

"""WirelessHART captures decoded whole (docs/wireless.md).

    import hartkit.wireless
    data = open("capture.pcapng", "rb").read()
    result = hartkit.wireless.decode(data, keys=["41424344414243444142434441424344"])
    for frame in result["frames"]:
        print(frame["index"], frame["type"], frame["src"], frame["dst"])
    print(result["summary"]["decrypted"])

Each frame is the object ``hartkit wireless decode --json`` prints: ``index``, ``type``
(``advertise``, ``ack``, ``keep-alive``, ``disconnect``, ``data`` or ``malformed``),
``seq``, ``src``, ``dst``, ``asn``, ``dl_mic_ok`` and, for data frames, ``nl`` with
``security``, ``counter``, ``decrypted`` and the ``commands``. Keys learned from the
traffic (the network key of command 961, the session keys of command 963) are used for
the frames that follow.
"""

from typing import Any, Dict, Iterable, Union

from ._native import wireless_decode as _decode

Key = Union[bytes, str]


def decode(data: bytes, keys: Iterable[Key] = (), network_keys: Iterable[Key] = ()) -> Dict[str, Any]:
    """Decodes the bytes of a pcap or pcapng capture of IEEE 802.15.4 frames (link types
    195, 230 or 283): ``{"frames": [...], "summary": {...}}``. ``keys`` are join keys,
    ``network_keys`` network keys, each 16 bytes or 32 hex digits. Raises
    ``hartkit.FrameError`` when the bytes are not such a capture, ``ValueError`` for a
    key that is not 16 bytes."""
    return _decode(bytes(data), list(keys), list(network_keys))


__all__ = ["decode"]

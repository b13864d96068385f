"""hartkit.wireless: a public WirelessHART capture (whad project, MIT) decoded whole."""

import pathlib

import pytest

import hartkit
import hartkit.wireless

CAPTURES = pathlib.Path(__file__).resolve().parents[2] / "hart-wireless" / "tests" / "captures"
JOIN_KEY = "41424344414243444142434441424344"


def test_capture_decodes_whole():
    data = (CAPTURES / "channel_13.pcap").read_bytes()
    result = hartkit.wireless.decode(data, keys=[JOIN_KEY])
    frames, summary = result["frames"], result["summary"]
    assert len(frames) == 993
    assert {f["type"] for f in frames} == {"advertise", "ack", "data"}
    assert summary["decrypted"] == 23 and summary["mic_failed"] == 0
    join = frames[509]
    assert join["src"] == "0001" and join["dst"] == "00170d000032d368"
    assert join["nl"]["security"] == "join" and join["nl"]["decrypted"]
    assert [c["command"] for c in join["nl"]["commands"]] == [963, 961, 962]
    assert join["nl"]["commands"][2]["fields"] == {"nickname": 2}


def test_key_as_bytes_and_without_keys():
    data = (CAPTURES / "channel_13.pcap").read_bytes()
    with_bytes = hartkit.wireless.decode(data, keys=[bytes.fromhex(JOIN_KEY)])
    assert with_bytes["summary"]["decrypted"] == 23
    without = hartkit.wireless.decode(data)
    assert without["summary"]["decrypted"] == 0
    assert without["frames"][509]["nl"]["decrypted"] is False


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        hartkit.wireless.decode(b"", keys=["abcd"])
    with pytest.raises(hartkit.FrameError):
        hartkit.wireless.decode(b"not a capture")

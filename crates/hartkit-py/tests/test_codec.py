"""The codec from Python against independent vectors (public manuals, logs and
captures, crates/hart-proto/tests/vectors/public.toml), and frames built here."""

import math

import pytest

import hartkit
from hartkit import commands


def subset(expect, got, path=""):
    """Every key of `expect` is in `got` with the same value (floats approximately;
    NaN, which the JSON view gives as None, matches None)."""
    for k, v in expect.items():
        assert k in got, f"{path}{k} missing in {got}"
        if isinstance(v, dict):
            subset(v, got[k], f"{path}{k}.")
        elif isinstance(v, list):
            assert len(v) == len(got[k]), f"{path}{k}"
            for i, (a, b) in enumerate(zip(v, got[k])):
                if isinstance(a, dict):
                    subset(a, b, f"{path}{k}[{i}].")
                else:
                    assert a == b, f"{path}{k}[{i}]"
        elif v == "nan" or (isinstance(v, float) and math.isnan(v)):
            assert got[k] is None or (isinstance(got[k], float) and math.isnan(got[k])), f"{path}{k}"
        elif isinstance(v, float):
            assert got[k] == pytest.approx(v, rel=1e-6), f"{path}{k}: {got[k]} != {v}"
        else:
            assert got[k] == v, f"{path}{k}: {got[k]!r} != {v!r}"


def test_every_public_vector_decodes_as_its_source_says(vectors):
    assert len(vectors) >= 40
    for v in vectors:
        raw = bytes.fromhex(v["hex"].replace(" ", ""))
        f = hartkit.Frame.parse(raw)
        d = f.to_dict()
        expect = dict(v.get("expect", {}))
        subset(expect, d, f"{v['name']}: ")
        assert f.to_bytes() == raw, v["name"]
        # The direct decoder and the JSON view agree.
        if "decoded" in d:
            assert f.decoded == d["decoded"], v["name"]
        assert f.frame_type == expect.get("frame_type", f.frame_type)
        assert f.command == expect.get("command", f.command)


def test_a_request_built_here_is_the_published_one():
    # Command 0 to polling address 0 with 5 preambles: the frame every HART manual prints.
    f = hartkit.Frame.request(0, 0)
    assert f.to_bytes() == bytes.fromhex("FFFFFFFFFF0280000082")
    assert (f.frame_type, f.command, f.polling_address, f.master) == ("STX", 0, 0, "primary")
    long = hartkit.Frame.request("2606BC614E", 1, preambles=0, secondary=True)
    assert long.unique_id == "2606BC614E" and long.master == "secondary"
    assert long.pdu == long.to_bytes()
    assert bytes(long) == long.to_bytes()
    back = hartkit.Frame.parse(long.to_bytes())
    assert back == long


def test_replies_and_burst_frames_are_built_and_decoded_in_words():
    # Command 1: units 12 (kPa) and a PV.
    data = bytes([12]) + bytes.fromhex("42F6E979")
    f = hartkit.Frame.reply("2606BC614E", 1, data, device_status=0x10)
    assert f.frame_type == "ACK" and f.response_code == 0 and f.device_status == 0x10
    d = f.decoded
    assert d["pv_units"] == 12 and d["pv_units_symbol"] == "kPa"
    assert d["pv"] == pytest.approx(123.456, rel=1e-6)
    b = hartkit.Frame.reply(1, 3, bytes(24), burst=True)
    assert b.frame_type == "BACK"
    typed = commands.ReadPrimaryVariable.decode_reply(data)
    assert typed.pv_units_symbol == "kPa" and typed.pv == pytest.approx(123.456, rel=1e-6)
    assert "pv" in typed and typed.to_dict()["pv_units"] == 12


def test_the_command_table_is_typed():
    assert commands.ReadDynamicVariables.number == 3
    assert commands.ReadDynamicVariables.kind == "universal"
    assert commands.WriteTagDescriptorDate.writes
    assert commands.by_number(48) is commands.ReadAdditionalStatus
    assert commands.by_number(200) is None
    assert len(commands.all_commands()) >= 50
    assert hartkit.unit(32) == ("°C", "degrees Celsius")
    assert hartkit.response_code_name(64) is not None


def test_bad_bytes_raise_errors_that_explain():
    with pytest.raises(hartkit.FrameError) as e:
        hartkit.Frame.parse(bytes.fromhex("FFFFFFFFFF0280000501"))
    assert "byte count" in str(e.value) and "only" in str(e.value)
    assert isinstance(e.value, hartkit.HartError)
    with pytest.raises(hartkit.FrameError):
        commands.ReadDynamicVariables.decode_reply(b"\x01\x02")
    with pytest.raises(ValueError) as e:
        hartkit.Frame.request(64, 0)
    assert "0-63" in str(e.value)
    with pytest.raises(ValueError):
        hartkit.Frame.request("XYZ", 0)
    for junk in [b"", b"\xff" * 40, bytes(range(256))]:
        with pytest.raises(hartkit.FrameError):
            hartkit.Frame.parse(junk)


def test_explain_is_the_cli_view():
    f = hartkit.Frame.request(0, 0)
    text = f.explain()
    assert "delimiter" in text and "Read Unique Identifier" in text
    assert "STX" in repr(f)


def test_a_stream_in_pieces_with_garbage_between():
    frames = [hartkit.Frame.request(p, 1) for p in range(1, 6)]
    stream = b"\x00\x13garbage" + b"".join(f.to_bytes() for f in frames)
    # A frame with a wrong check byte in the middle.
    bad = bytearray(hartkit.Frame.request(9, 1).to_bytes())
    bad[-1] ^= 0xFF
    stream += bytes(bad) + hartkit.Frame.reply(1, 1, bytes(5)).to_bytes()
    d = hartkit.Deframer()
    got = []
    for i in range(0, len(stream), 7):
        got += d.feed(stream[i : i + 7])
    assert [f.polling_address for f in got] == [1, 2, 3, 4, 5, 1]
    assert got[-1].frame_type == "ACK"
    assert (d.frames, d.damaged) == (6, 1)


def test_requests_and_replies_are_built_from_their_fields():
    # Tag "PT-101" packs to 41 4B 71 C3 18 20 (hart-reference.md §10.1); the date is
    # day, month, year - 1900.
    data = commands.WriteTagDescriptorDate.encode_request(tag="PT-101", descriptor="FEED PUMP", date="2025-11-21")
    assert data[:6] == bytes.fromhex("414B71C31820") and data[-3:] == bytes([21, 11, 125])
    # Units by symbol or by code; a dict, a Record and keywords are the same.
    assert commands.WritePvUnits.encode_request(pv_units="kPa") == bytes([12])
    assert hartkit.encode_request(44, {"pv_units": 12}) == bytes([12])
    reply = bytes([12]) + bytes.fromhex("42F6E979")
    typed = commands.ReadPrimaryVariable.decode_reply(reply)
    assert commands.ReadPrimaryVariable.encode_reply(typed) == reply
    # Lists of codes, lists of objects, raw bytes as bytes or hex.
    assert commands.ReadDeviceVariablesWithStatus.encode_request(slots=[0, 1, 246]) == bytes([0, 1, 246])
    assert hartkit.encode_reply(48, additional_status=b"\x01\x02") == b"\x01\x02"


def test_every_public_vector_goes_back_from_its_decoded_fields(vectors):
    checked = 0
    for v in vectors:
        f = hartkit.Frame.parse(bytes.fromhex(v["hex"].replace(" ", "")))
        if "decoded" not in f.to_dict():
            continue  # a damaged frame, an error reply, or a command hartkit does not type
        d = f.decoded
        if f.frame_type == "STX":
            back = hartkit.encode_request(f.command, d)
            again = hartkit.decode_request(f.command, back)
        else:
            back = hartkit.encode_reply(f.command, d)
            again = hartkit.decode_reply(f.command, back)
        # Surplus bytes a device sent are not part of the layout: compare views, and
        # bytes wherever the data is exactly the layout.
        assert again == d, v["name"]
        if len(back) == len(f.data):
            assert back == f.data, v["name"]
        checked += 1
    assert checked >= 20


def test_fields_that_do_not_fit_raise_errors_that_name_them():
    with pytest.raises(hartkit.FrameError) as e:
        commands.WritePvUnits.encode_request(pv_unit="kPa")
    assert "no field pv_unit; the fields are pv_units" in str(e.value)
    with pytest.raises(hartkit.FrameError) as e:
        commands.WritePollingAddress.encode_request(polling_address=300)
    assert "polling_address" in str(e.value) and "0 to 255" in str(e.value)
    with pytest.raises(hartkit.FrameError) as e:
        commands.WriteTagDescriptorDate.encode_request(tag="PT-101")
    assert "descriptor is missing" in str(e.value)
    with pytest.raises(hartkit.FrameError) as e:
        commands.WriteTagDescriptorDate.encode_request(tag="A TAG TOO LONG", descriptor="", date="2025-01-01")
    assert "tag" in str(e.value) and "too long" in str(e.value)
    with pytest.raises(hartkit.FrameError) as e:
        hartkit.encode_request(200, {})
    assert "no layout for command 200" in str(e.value)
    with pytest.raises(hartkit.FrameError):
        commands.WritePvUnits.encode_request(pv_units=object())

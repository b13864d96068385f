"""The host from Python: the in-process simulated plant (virtual time), and a separate
`hartkit serve --sim` over HART-IP; asyncio and the blocking API."""

import asyncio
import subprocess
import json

import pytest

import hartkit
import hartkit.sync


def run(coro):
    return asyncio.run(coro)


def test_scan_read_and_write_with_asyncio():
    async def main():
        async with hartkit.connect("sim?virtual") as loop:
            assert "simulated plant" in loop.description
            found = await loop.scan(0, 20)
            assert [d.polling_address for d in found] == [1, 2, 3, 17]
            assert found[0].tag == "PT-100" and found[0].universal_revision == 7
            assert found[0].revision == 7 and found[0].io_channel is None  # the aliases
            assert found[0].identity.universal_revision == 7
            dev = await loop.device(poll=1)
            r = await dev.read_dynamic()
            assert r.command == 3 and r.response_code == 0
            assert r.variables[0].units_symbol == "kPa"
            assert isinstance(r.loop_current, float)
            assert r.frame.frame_type == "ACK"
            # Command 9 with the codes given, built from its layout.
            v = await dev.read_variables(0, 1)
            assert v.command == 9 and v.response_code == 0
            assert [s.code for s in v.slots] == [0, 1]
            by_tag = await loop.device(tag="TT-200")
            # Found by tag (command 11), it keeps the polling address the scan found.
            assert by_tag.info.polling_address == 2
            back = await dev.write_tag("PY-1")
            assert back.tag == "PY-1"
            again = await loop.device(tag="PY-1")
            assert again.info.unique_id == dev.info.unique_id
            d = await dev.write_damping(2.5)
            assert d.damping == pytest.approx(2.5) and d.range_units_symbol == "kPa"
            # A typed request from its fields: command 44 by class, units by symbol.
            u = await dev.request(hartkit.commands.WritePvUnits, pv_units="bar")
            assert u.response_code == 0 and u.pv_units_symbol == "bar"
            pv = await dev.request(1)
            assert pv.pv_units_symbol == "bar"

    run(main())


def test_errors_from_the_loop_are_typed_and_explain():
    async def main():
        loop = await hartkit.connect("sim?virtual")
        try:
            with pytest.raises(hartkit.NoReplyError) as e:
                await loop.device(poll=9)
            assert "polling address 9" in str(e.value)
            dev = await loop.device(poll=1)
            with pytest.raises(hartkit.DeviceError) as e:
                await dev.command(200)
            assert e.value.response_code == 64 and e.value.command == 200
            with pytest.raises(ValueError):
                await loop.device(poll=1, tag="X")
        finally:
            await loop.close()
        with pytest.raises(hartkit.TargetError):
            await loop.scan()

    run(main())
    async def bad():
        return await hartkit.connect("carrier-pigeon://x")

    with pytest.raises(hartkit.TargetError) as e:
        run(bad())
    assert "carrier-pigeon" in str(e.value)


def test_bursts_arrive_with_async_for():
    async def main():
        async with hartkit.connect("sim?virtual") as loop:
            got = []
            async for f in loop.bursts():
                got.append(f)
                if len(got) == 2:
                    break
            assert all(f.frame_type == "BACK" and f.command == 3 for f in got)

    run(main())


def test_many_requests_at_once_are_served_in_turn():
    async def main():
        async with hartkit.connect("sim?virtual") as loop:
            devs = [await loop.device(poll=p) for p in (1, 2, 3)]
            replies = await asyncio.gather(*(d.read_pv() for d in devs for _ in range(3)))
            assert len(replies) == 9 and all(r.response_code == 0 for r in replies)

    run(main())


def test_the_blocking_api():
    with hartkit.sync.connect("sim?virtual") as loop:
        found = loop.scan(1, 3)
        assert len(found) == 3
        dev = loop.device(poll=3)
        r = dev.command(1)
        assert r.pv_units == 57 and r.pv_units_symbol == "%"  # valve travel in percent
        reply, read_back = dev.write("descriptor", "FROM PYTHON")
        assert read_back.descriptor.startswith("FROM PYTHON")
        frames = loop.listen(5)
        assert frames and frames[0].frame_type == "BACK"


def test_a_hart_ip_server_in_another_process(hart_ip_server, hartkit_bin):
    async def main():
        async with hartkit.connect(hart_ip_server) as loop:
            assert "HART-IP" in loop.description or "udp" in loop.description
            dev = await loop.device(poll=1)
            r = await dev.read_dynamic()
            return dev.info.unique_id, r.variables[0].units_symbol

    uid, units = run(main())
    assert units == "kPa"
    # The CLI sees the same device behind the server.
    out = subprocess.run(
        [hartkit_bin, "read", "-p", hart_ip_server, "--poll", "1", "pv", "--json"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert json.loads(out.stdout)["units_symbol"] == "kPa"
    assert uid

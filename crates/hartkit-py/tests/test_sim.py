"""The network simulation from Python gives the figures of `hartkit sim bench`."""

import json
import subprocess

import hartkit
import hartkit.sync


def cli(hartkit_bin, *args):
    """The command line, run to its end (60 s at most); its CompletedProcess."""
    return subprocess.run([hartkit_bin, *args], capture_output=True, text=True, timeout=60)


def test_bench_matches_the_command_line(hartkit_bin):
    py = hartkit.sim.bench(devices=3, duration=30, secondary=True, burst=True)
    cli = json.loads(
        subprocess.run(
            [hartkit_bin, "sim", "bench", "--devices", "3", "--duration", "30", "--secondary", "--burst", "--json"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    )
    for key in ["transactions", "burst_frames", "failed", "retries", "collisions", "devices_found", "efficiency"]:
        assert py[key] == cli[key], key


def test_bench_on_the_analog_loop():
    r = hartkit.sim.bench(devices=2, duration=20, analog=True, cable_m=1000)
    assert r["medium"]["kind"] == "analog"
    assert r["frames_sent"] > 10 and r["frame_error_rate"] == 0


def test_devices_served_from_python_are_read_by_the_cli(hartkit_bin):
    with hartkit.sim.serve_hart_ip(["pressure", "valve"]) as server:
        assert server.target.startswith("udp://127.0.0.1:") and server.port
        out = subprocess.run(
            [hartkit_bin, "read", "-p", server.target, "--poll", "2", "pv", "--json"],
            capture_output=True,
            text=True,
            check=True,
        )
        assert json.loads(out.stdout)["units_symbol"] == "%"
        # And by this package, over TCP.
        with hartkit.sync.connect(server.tcp_target) as loop:
            assert [d.polling_address for d in loop.scan(1, 3)] == [1, 2]
    # Closed: nobody answers any more.
    gone = cli(hartkit_bin, "read", "-p", server.target, "--poll", "1", "pv")
    assert gone.returncode != 0


def test_serving_explains_what_is_wrong():
    import pytest

    with pytest.raises(hartkit.TargetError) as e:
        hartkit.sim.serve_hart_ip(["no-such-profile"])
    assert "no-such-profile" in str(e.value)
    with pytest.raises(ValueError):
        hartkit.sim.serve_hart_ip(address="nowhere")


def test_a_python_device_handler_answers_the_cli(hartkit_bin):
    import struct

    def read_pv(data):
        return bytes([12]) + struct.pack(">f", 42.5)

    def refuse(data):
        return (5, b"")  # too few data bytes

    with hartkit.sim.PythonDevice({1: read_pv, 6: refuse}, poll=0) as dev:
        out = cli(hartkit_bin, "read", "-p", f"serial:{dev.path}", "--poll", "0", "pv", "--json")
        assert out.returncode == 0, out.stderr
        pv = json.loads(out.stdout)
        assert pv["pv"] == 42.5 and pv["units_symbol"] == "kPa"
        # Command 0 (short frame) found it, command 1 went in a long frame.
        assert [f.command for f in dev.requests] == [0, 1]
        assert dev.requests[1].unique_id == dev.unique_id
        refused = cli(hartkit_bin, "command", "-p", f"serial:{dev.path}", "--poll", "0", "6", "00")
        assert refused.returncode != 0 and "5" in refused.stderr


def test_a_python_device_answers_with_fields_and_the_cli_sends_fields(hartkit_bin):
    # The handler returns the reply's fields, not bytes; the CLI sends command 44's
    # request as JSON fields, which the handler reads back typed.
    seen = []

    def read_pv(data):
        return {"pv_units": "degrees Celsius", "pv": 21.5}

    def write_units(data):
        req = hartkit.commands.WritePvUnits.decode_request(data)
        seen.append(req.pv_units_symbol)
        return req

    with hartkit.sim.PythonDevice({1: read_pv, 44: write_units}, poll=0) as dev:
        out = cli(hartkit_bin, "read", "-p", f"serial:{dev.path}", "--poll", "0", "pv", "--json")
        assert out.returncode == 0, out.stderr
        pv = json.loads(out.stdout)
        assert pv["pv"] == 21.5 and pv["units_symbol"] == "°C"
        out = cli(hartkit_bin, "command", "-p", f"serial:{dev.path}", "--poll", "0", "44", '{"pv_units": "kPa"}', "--json")
        assert out.returncode == 0, out.stderr
        assert json.loads(out.stdout)["decoded"]["pv_units"] == 12
        assert seen == ["kPa"]


def test_a_server_that_vanishes_mid_session_is_an_error_that_explains():
    import pytest

    server = hartkit.sim.serve_hart_ip(["pressure"])
    loop = hartkit.sync.connect(server.target)
    dev = loop.device(poll=1)
    assert dev.read_pv().response_code == 0
    server.close()
    with pytest.raises(hartkit.HartError) as e:
        dev.read_pv()
    assert "stopped answering" in str(e.value) or "no reply" in str(e.value).lower(), str(e.value)
    loop.close()


def test_a_python_device_behind_hart_ip_answers_a_hart_ip_host(hartkit_bin):
    # Python handlers, reached over HART-IP: the asyncio host and the CLI (a separate
    # process) read the handler's value through the server and the pseudo-terminal.
    def read_pv(data):
        return {"pv_units": "kPa", "pv": 7.25}

    with hartkit.sim.PythonDevice({1: read_pv}, poll=0) as dev:
        with dev.serve_hart_ip() as server:
            with hartkit.sync.connect(server.target) as loop:
                d = loop.device(poll=0)
                assert d.info.unique_id == dev.unique_id
                r = d.command(1)
                assert r.pv == 7.25 and r.pv_units_symbol == "kPa"
            out = cli(hartkit_bin, "read", "-p", server.tcp_target, "--poll", "0", "pv", "--json")
            assert out.returncode == 0, out.stderr
            assert json.loads(out.stdout)["pv"] == 7.25
        assert any(f.command == 1 for f in dev.requests)

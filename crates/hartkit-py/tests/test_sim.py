"""The network simulation from Python gives the figures of `hartkit sim bench`."""

import json
import subprocess

import hartkit


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

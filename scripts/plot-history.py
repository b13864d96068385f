#!/usr/bin/env python3
"""Plots what the gateway's historian holds: for every stored device, its PV (in its
units) and its percent of range, over the whole stored time, one row of panels per
device, into a PNG. It reads the file as a user does, through `hartkit history
devices --json` and `hartkit history query --json`.

Usage: scripts/plot-history.py DB PNG   (needs matplotlib; HARTKIT names the binary,
default `hartkit` on the PATH)

The picture in docs/history.md and the README:
    hartkit serve --sim --history plant.sqlite --poll-period 1 --run-for 240
    scripts/plot-history.py plant.sqlite docs/history-trend.png
"""
import datetime
import json
import os
import subprocess
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.dates as mdates
import matplotlib.pyplot as plt

UNITS = {32: "°C", 12: "kPa", 7: "bar", 57: "%", 39: "mA", 19: "m³/h", 8: "mbar"}

db, dst = sys.argv[1], sys.argv[2]
hartkit = os.environ.get("HARTKIT", "hartkit")


def run(*args):
    out = subprocess.run([hartkit, *args], check=True, capture_output=True, text=True)
    return json.loads(out.stdout)


def series(device, var, start, end):
    rows = run("history", "query", "--db", db, "--device", device, "--var", var,
               "--from", start, "--to", end, "--json")
    t = [datetime.datetime.fromisoformat(r["time"].replace("Z", "+00:00")) for r in rows]
    v = [r["value"] for r in rows]
    units = next((r["units"] for r in rows if r["units"] is not None), None)
    return t, v, units


devices = run("history", "devices", "--db", db, "--json")
fig, axes = plt.subplots(len(devices), 2, figsize=(11, 2.1 * len(devices)), squeeze=False,
                         sharex=True)
for row, d in zip(axes, devices):
    end = (datetime.datetime.fromisoformat(d["last"].replace("Z", "+00:00"))
           + datetime.timedelta(seconds=1)).strftime("%Y-%m-%dT%H:%M:%SZ")
    for ax, var, title in [(row[0], "pv", "PV"), (row[1], "percent_range", "percent of range")]:
        t, v, units = series(d["unique_id"], var, d["first"], end)
        ax.step(t, v, where="post", lw=1.2)
        ax.set_title(f"{d['tag']} ({d['unique_id']}): {title}", fontsize=9)
        ax.set_ylabel(UNITS.get(units, f"units {units}"), fontsize=8)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_formatter(mdates.DateFormatter("%H:%M:%S"))
fig.suptitle("The demo plant from the historian (hartkit history query)", fontsize=10)
fig.tight_layout()
fig.savefig(dst, dpi=90)
print(f"wrote {dst}")

#!/usr/bin/env python3
"""Plots the CSVs of `hartkit loop cable --table --simulate --sweep N --csv FILE` as
frame error rate against cable length, one curve per cable capacitance, with the RC
rule's length for the same network as a dashed line: one panel per CSV, into a PNG.

Usage: scripts/plot-cable.py PNG CSV=TITLE [CSV=TITLE ...]   (needs matplotlib)

Environment: DEVICES picks the cells with that many devices (default 1).
"""
import csv
import os
import sys
from collections import defaultdict

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

dst = sys.argv[1]
panels = [a.split("=", 1) if "=" in a else (a, a) for a in sys.argv[2:]]
devices = int(os.environ.get("DEVICES", "1"))


def load(path):
    curves, rules = defaultdict(dict), {}
    for row in csv.DictReader(open(path)):
        if int(row["devices"]) != devices:
            continue
        pf = float(row["pf_per_m"])
        length, frames = float(row["length_m"]), int(row["frames"])
        # Where a length was measured twice, the measurement with more frames wins.
        if length not in curves[pf] or curves[pf][length][1] < frames:
            curves[pf][length] = (float(row["fer"]), frames)
        rules[pf] = float(row["rule_m"])
    return curves, rules


fig, axes = plt.subplots(1, len(panels), figsize=(6.2 * len(panels), 4.6), dpi=110, sharey=True)
if len(panels) == 1:
    axes = [axes]
colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
for ax, (path, title) in zip(axes, panels):
    curves, rules = load(path)
    for k, pf in enumerate(sorted(curves)):
        pts = sorted(curves[pf].items())
        c = colors[k % len(colors)]
        ax.plot([x / 1000 for x, _ in pts], [f for _, (f, _) in pts], "o-", ms=3, color=c,
                label=f"{pf:g} pF/m")
        ax.axvline(rules[pf] / 1000, ls="--", color=c, lw=1)
    ax.axhline(0.001, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("cable length (km)")
    ax.set_ylim(-0.02, 1.0)
    ax.set_xlim(left=0)
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8, title="solid: simulated\ndashed: RC rule",
              title_fontsize=8)
axes[0].set_ylabel("frame error rate")
fig.suptitle(f"{devices} device(s) on a 250 Ω loop: frames lost against cable length", fontsize=11)
fig.tight_layout()
fig.savefig(dst)
print(f"wrote {dst}")

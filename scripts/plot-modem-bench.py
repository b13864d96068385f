#!/usr/bin/env python3
"""Plots docs/modem-bench.csv (written by `hartkit modem bench`) as frame error rate
against Eb/N0, with the theoretical curves for a 311-bit frame, into docs/modem-fer.png.

Usage: scripts/plot-modem-bench.py [CSV] [PNG]   (needs matplotlib and scipy)

Theory (per bit, h = 5/6 continuous-phase FSK; see ../shared physical-layer notes):
  coherent sequence detection (MLSE), d²min = 2.331:  Pb = Q(sqrt(2.331·Eb/N0))
  coherent one bit at a time, rho = -0.165:           Pb = Q(sqrt((1 - rho)·Eb/N0))
  non-coherent one bit at a time, |rho| = 0.191:      Marcum-Q formula
and FER = 1 - (1 - Pb)^311 for the average benchmark frame.
"""
import csv
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from scipy.special import i0e
from scipy.stats import ncx2, norm

src = sys.argv[1] if len(sys.argv) > 1 else "docs/modem-bench.csv"
dst = sys.argv[2] if len(sys.argv) > 2 else "docs/modem-fer.png"
rows = list(csv.DictReader(open(src)))
BITS = 311


def fer(pb):
    return 1 - (1 - np.clip(pb, 0, 1)) ** BITS


def q(x):
    return norm.sf(x)


def noncoherent(g, rho=0.191):
    # Binary non-coherent detection of non-orthogonal equal-energy signals.
    k = np.sqrt(1 - rho * rho)
    a = np.sqrt(g / 2 * (1 - k))
    b = np.sqrt(g / 2 * (1 + k))
    q1 = ncx2.sf(b * b, 2, a * a)  # Marcum Q1(a, b)
    return q1 - 0.5 * np.exp(-(a - b) ** 2 / 2) * i0e(a * b)


db = np.linspace(6, 17, 200)
g = 10 ** (db / 10)
fig, ax = plt.subplots(figsize=(8, 5.5))
ax.semilogy(db, fer(q(np.sqrt(2.331 * g))), "k--", lw=1, label="coherent MLSE (floor)")
ax.semilogy(db, fer(q(np.sqrt(1.165 * g))), "k-.", lw=1, label="coherent, one bit at a time")
ax.semilogy(db, fer(noncoherent(g)), "k:", lw=1.2, label="non-coherent, one bit at a time")


def series(group, name_filter=lambda r: True):
    pts = [(float(r["ebn0_db"]), float(r["fer"]), r) for r in rows if r["group"] == group and name_filter(r)]
    return sorted(pts, key=lambda p: p[0])


awgn = series("awgn")
# Zero errors cannot be drawn on a log scale: put them at a third of one error.
frames = max(int(p[2]["sent"]) for p in awgn)
floor = 1 / (3 * frames)
zero_at = f"{floor:.0e}".replace("e-0", "e-")
x = [p[0] for p in awgn]
ax.semilogy(x, [max(p[1], floor) for p in awgn], "o-", color="C0", lw=2, label="hartkit (white noise)")
mm = [(p[0], 1 - int(p[2]["minimodem_good"]) / int(p[2]["sent"])) for p in awgn if p[2]["minimodem_good"]]
if mm:
    ax.semilogy([m[0] for m in mm], [max(m[1], floor) for m in mm], "s-", color="C3", label="minimodem --binary-raw 11 + 8O1")
markers = {"offset": ("^", "C1"), "rc": ("D", "C2")}
for r in rows:
    if r["group"] in markers and r["ebn0_db"]:
        m, c = markers[r["group"]]
        ax.semilogy(float(r["ebn0_db"]) + 0.05, max(float(r["fer"]), floor), m, color=c, ms=5, alpha=0.7)
ax.plot([], [], "^", color="C1", label="hartkit, tone/bit-rate error ±1 %, ±2 %")
ax.plot([], [], "D", color="C2", label="hartkit, cable RC 65 µs")
ax.axhline(0.01, color="grey", lw=0.5)
ax.axhline(0.001, color="grey", lw=0.5)
ax.set_ylim(floor * 0.8, 1.2)
ax.set_xlim(6, 17)
ax.set_xlabel("Eb/N0 (dB)")
ax.set_ylabel(f"frame error rate (311-bit frames; zero errors drawn at {zero_at})")
ax.set_title(f"HART FSK demodulators, {frames} random frames per point, 48 kHz")
ax.grid(True, which="both", alpha=0.3)
ax.legend(fontsize=8, loc="lower left")
fig.tight_layout()
fig.savefig(dst, dpi=110)
print("wrote", dst)

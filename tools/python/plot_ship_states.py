#!/usr/bin/env python3
"""Error vs chain states on the ship, from `beliefbus experiment ship-states
--json` files: one line per JSON (its chain rows), PF rows as a horizontal
band (mean ± 95 % CI). Plain SVG, no dependencies.

usage: plot_ship_states.py OUT.svg LABEL=FILE.json [LABEL=FILE.json ...]
"""
import json
import math
import sys

W, H, L, R, T, B = 640, 400, 60, 170, 20, 45
COLOURS = ["#1f77b4", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2"]


def main():
    out, series = sys.argv[1], [a.rsplit("=", 1) for a in sys.argv[2:]]
    data, pf = [], None
    for label, path in series:
        rows = json.load(open(path))["results"]
        pf = pf or next(r for r in rows if r["method"] == "pf")
        pts = [(r["states"], r["mean_error"], r["ci95"]) for r in rows if r["method"] != "pf"]
        data.append((label, pts))
    xs = [p[0] for _, pts in data for p in pts]
    x0, x1 = math.log10(min(xs)) - 0.1, math.log10(max(xs)) + 0.1
    y0, y1 = 0.3, 1.6
    sx = lambda n: L + (math.log10(n) - x0) / (x1 - x0) * (W - L - R)
    sy = lambda e: T + (y1 - min(max(e, y0), y1)) / (y1 - y0) * (H - T - B)
    s = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" font-family="sans-serif" font-size="11">']
    s.append(f'<rect x="{L}" y="{T}" width="{W-L-R}" height="{H-T-B}" fill="none" stroke="#888"/>')
    lo, hi = pf["mean_error"] - pf["ci95"], pf["mean_error"] + pf["ci95"]
    s.append(f'<rect x="{L}" y="{sy(hi):.1f}" width="{W-L-R}" height="{sy(lo)-sy(hi):.1f}" fill="#ff7f0e" opacity="0.2"/>')
    s.append(f'<line x1="{L}" x2="{W-R}" y1="{sy(pf["mean_error"]):.1f}" y2="{sy(pf["mean_error"]):.1f}" stroke="#ff7f0e"/>')
    for e in [0.4, 0.6, 0.8, 1.0, 1.2, 1.4]:
        s.append(f'<text x="{L-6}" y="{sy(e)+4:.1f}" text-anchor="end">{e:.1f}</text>')
    for n in [100, 300, 1000, 3000, 10000, 30000]:
        if x0 <= math.log10(n) <= x1:
            s.append(f'<text x="{sx(n):.1f}" y="{H-B+15}" text-anchor="middle">{n}</text>')
    s.append(f'<text x="{(L+W-R)/2}" y="{H-8}" text-anchor="middle">chain states n</text>')
    s.append(f'<text x="14" y="{(T+H-B)/2}" transform="rotate(-90 14 {(T+H-B)/2})" text-anchor="middle">mean error E[(1/T)∫‖x − x̂‖dt]</text>')
    for i, (label, pts) in enumerate(data):
        c = COLOURS[i % len(COLOURS)]
        path = " ".join(f"{sx(n):.1f},{sy(e):.1f}" for n, e, _ in pts)
        s.append(f'<polyline points="{path}" fill="none" stroke="{c}" stroke-width="1.5"/>')
        for n, e, ci in pts:
            s.append(f'<line x1="{sx(n):.1f}" x2="{sx(n):.1f}" y1="{sy(e-ci):.1f}" y2="{sy(e+ci):.1f}" stroke="{c}"/>')
            s.append(f'<circle cx="{sx(n):.1f}" cy="{sy(e):.1f}" r="2.5" fill="{c}"/>')
        s.append(f'<text x="{W-R+8}" y="{T+14+16*i}" fill="{c}">{label}</text>')
    s.append(f'<text x="{W-R+8}" y="{T+14+16*len(data)}" fill="#ff7f0e">PF-{pf["states"]} (± 95 % CI)</text>')
    s.append("</svg>")
    open(out, "w").write("\n".join(s) + "\n")


if __name__ == "__main__":
    main()

#!/usr/bin/python3
"""Plots of `dtif bench` output (scripts/bench.sh): precision-recall over the acceptance
threshold (inliers; scan context: its distance), error distributions, time per stage vs trunks
per submap, query time vs database size; with --speed (scripts/bench_speed.sh): query time vs
database size and descriptor time vs points per submap, before and after.
Usage: bench_plots.py <bench_dir>"""
import csv
import sys
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def finish(fig, ax, path, xlabel, ylabel, log=()):
    """Labels, log axes, legend, then saves and closes the figure."""
    for axis in log:
        getattr(ax, "set_%sscale" % axis)("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def speed_plots(out):
    """speed_vs_database.png and speed_vs_points.png from speed_scale.csv, speed_describe.csv."""
    fig, ax = plt.subplots(figsize=(6, 4.5))
    scale = rows(out / "speed_scale.csv")
    for build, style in [("before", "--"), ("after", "-")]:
        rs = [r for r in scale if r["build"] == build]
        if not rs:
            continue
        n = [int(float(r["db_size"])) for r in rs]
        for key, mark in [("median_ms", "o"), ("mean_ms", "x")]:
            ax.plot(n, [float(r[key]) for r in rs], ls=style, marker=mark,
                    label="%s: query %s" % (build, key[:-3]))
    for target, n in [(5, 1000), (10, 10000)]:
        ax.plot([n], [target], marker="*", ms=12, ls="none", color="k")
    ax.plot([], [], marker="*", ls="none", color="k", label="target (issue #18)")
    ax.set_title("Loop query vs database size (thread CPU)")
    finish(fig, ax, out / "speed_vs_database.png", "database size [entries]", "ms per query",
           log="xy")

    fig, ax = plt.subplots(figsize=(6, 4.5))
    desc = rows(out / "speed_describe.csv")
    for build, mark in [("before", "x"), ("after", "o")]:
        rs = [r for r in desc if r["build"] == build]
        if rs:
            ax.scatter([float(r["points"]) / 1e6 for r in rs], [float(r["min_ms"]) for r in rs],
                       s=10, marker=mark, label=build)
    ax.axhline(25, color="k", ls=":", label="target at ~1 M points (issue #18)")
    ax.set_title("Descriptor time vs points per submap (thread CPU)")
    finish(fig, ax, out / "speed_vs_points.png", "points per submap [millions]",
           "ms per submap (extraction + descriptor)")


def main(out):
    out = Path(out)
    if (out / "speed_scale.csv").exists():
        speed_plots(out)
    if not (out / "summary.csv").exists():  # dtif bench --speed-only
        return
    # Precision-recall over the acceptance threshold (all scenes pooled). Scan context and
    # "dtif (place recognition)" count an answer as correct when it is a true loop.
    pr = defaultdict(lambda: defaultdict(lambda: [0, 0, 0]))  # method -> k -> [acc, tp, loops]
    loops = {}
    for r in rows(out / "summary.csv"):
        if r["scene"] != "all" and r["table"] == "back_end":
            loops[r["scene"]] = int(r["queries_with_loop"])
    for r in rows(out / "pr.csv"):
        acc = pr[r["method"]][float(r["threshold"])]
        acc[0] += int(r["accepted"])
        acc[1] += int(r["true_positives"])
        acc[2] += loops.get(r["scene"], 0)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for method, ks in pr.items():
        pts = sorted(ks.items())
        rec = [tp / lp if lp else 0 for _, (a, tp, lp) in pts]
        prec = [tp / a if a else 1.0 for _, (a, tp, lp) in pts]
        ax.plot(rec, prec, marker=".", label=method)
    ax.set_title("Precision-recall over the acceptance threshold (all scenes)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.05)
    finish(fig, ax, out / "pr_curve.png", "recall", "precision")

    # Error distributions of accepted loops per method (all scenes).
    errs = defaultdict(lambda: ([], []))
    for f in sorted(out.glob("*/results_*.csv")):
        method = f.stem[len("results_"):]
        for r in rows(f):
            if r["accepted"] == "1":
                errs[method][0].append(float(r["err_rot_deg"]))
                errs[method][1].append(float(r["err_trans_m"]))
    names = sorted(errs)
    fig, axs = plt.subplots(1, 2, figsize=(12, 0.35 * len(names) + 2))
    for k, (ax, unit) in enumerate(zip(axs, ["rotation error [deg]", "translation error [m]"])):
        data = [errs[m][k] or [float("nan")] for m in names]
        ax.boxplot(data, vert=False, labels=names if k == 0 else [""] * len(names))
        ax.set_xscale("log")
        ax.set_xlabel(unit)
        ax.tick_params(axis="y", labelsize=7)
    fig.suptitle("Errors of accepted loops (all scenes)")
    fig.tight_layout()
    fig.savefig(out / "error_distributions.png", dpi=120)
    plt.close(fig)

    # Time per stage vs trunks per submap.
    sub = rows(out / "submaps.csv")
    fig, ax = plt.subplots(figsize=(6, 4.5))
    tr = [int(r["trunks"]) for r in sub]
    for key, label in [("t_extract_ms", "trunk extraction"), ("t_desc_ms", "descriptor (incl. extraction)"),
                       ("t_loop_ms", "loop query"), ("t_fpfh_ms", "FPFH features (baseline)"),
                       ("t_scan_context_ms", "scan context (baseline)")]:
        if key in sub[0]:  # reports older than the scan-context baseline lack its column
            ax.scatter(tr, [float(r[key]) for r in sub], s=8, label=label)
    finish(fig, ax, out / "time_vs_trunks.png", "trunks per submap", "ms per submap (one thread)",
           log="y")

    # Query time vs database size.
    sc = out / "scaling.csv"
    if sc.exists():
        fig, ax = plt.subplots(figsize=(6, 4.5))
        by = defaultdict(list)
        for r in rows(sc):
            by[r["indexed"]].append(r)
        for idx, rs in sorted(by.items()):
            n = [int(r["db_size"]) for r in rs]
            lab = "coarse index" if idx == "1" else "linear screening"
            ax.plot(n, [float(r["query_ms"]) for r in rs], marker="o", label=lab + ": query")
            ax.plot(n, [float(r["screen_ms"]) for r in rs], marker="x", ls="--",
                    label=lab + ": screening")
        finish(fig, ax, out / "query_vs_database.png", "database size [submaps]", "ms per query",
               log="xy")


if __name__ == "__main__":
    main(sys.argv[1])

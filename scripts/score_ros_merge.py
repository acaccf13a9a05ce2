#!/usr/bin/env python3
"""Scores the map merge nodelet's saved map (save_map: merged_poses.csv, submap_ids.csv) against
a dataset's ground truth, as DATASET.md's ATE but aligned in yaw and translation only (both the
map frame and the world are z up, gravity), per robot and over all robots of each map frame.
Usage: score_ros_merge.py <dataset_dir> <map_dir>"""
import csv
import math
import sys


def align_rms(est, gt):
    """RMS residual [m] after the yaw + translation that best maps est onto gt."""
    n = len(est)
    ce = [sum(p[i] for p in est) / n for i in range(3)]
    cg = [sum(p[i] for p in gt) / n for i in range(3)]
    s_dot = s_cross = 0.0
    for e, g in zip(est, gt):
        ex, ey = e[0] - ce[0], e[1] - ce[1]
        gx, gy = g[0] - cg[0], g[1] - cg[1]
        s_dot += ex * gx + ey * gy
        s_cross += ex * gy - ey * gx
    yaw = math.atan2(s_cross, s_dot)
    c, s = math.cos(yaw), math.sin(yaw)
    sq = 0.0
    for e, g in zip(est, gt):
        ex, ey, ez = e[0] - ce[0], e[1] - ce[1], e[2] - ce[2]
        r = (c * ex - s * ey + cg[0] - g[0], s * ex + c * ey + cg[1] - g[1], ez + cg[2] - g[2])
        sq += sum(v * v for v in r)
    return math.sqrt(sq / n)


def main():
    ds, mp = sys.argv[1], sys.argv[2]
    gt = {r["id"]: [float(r[k]) for k in ("tx", "ty", "tz")]
          for r in csv.DictReader(open(ds + "/ground_truth.csv"))}
    subs = list(csv.DictReader(open(ds + "/submaps.csv")))
    odom = {r["id"]: [float(r["odom_" + k]) for k in ("tx", "ty", "tz")] for r in subs}
    ids = {r["id"]: r for r in csv.DictReader(open(mp + "/submap_ids.csv"))}
    by_comp, by_robot = {}, {}
    for r in csv.DictReader(open(mp + "/merged_poses.csv")):
        k = ids[r["id"]]
        # The dataset submap of the same robot and anchor stamp.
        match = [s["id"] for s in subs
                 if s["robot"] == k["robot"] and abs(float(s["stamp"]) - float(k["stamp"])) < 1e-3]
        if not match:
            continue
        p = [float(r[c]) for c in ("tx", "ty", "tz")]
        by_comp.setdefault(r["component"], []).append((p, gt[match[0]], k["robot"]))
        by_robot.setdefault(k["robot"], []).append(match[0])
    print("map frame component  robots        submaps  ATE [m]")
    for comp, rows in sorted(by_comp.items()):
        robots = sorted({r[2] for r in rows})
        print("%19s  %-12s  %7d  %7.3f" % (comp, ",".join(robots), len(rows),
                                          align_rms([r[0] for r in rows], [r[1] for r in rows])))
    print("robot (each aligned alone)  submaps  merged ATE [m]  odometry-only ATE [m]")
    for robot, mine in sorted(by_robot.items()):
        rows = [r for rs in by_comp.values() for r in rs if r[2] == robot]
        print("%-26s  %7d  %14.3f  %21.3f" % (robot, len(rows),
                                             align_rms([r[0] for r in rows], [r[1] for r in rows]),
                                             align_rms([odom[i] for i in mine],
                                                       [gt[i] for i in mine])))


if __name__ == "__main__":
    main()

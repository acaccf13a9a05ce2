#!/usr/bin/env python3
"""Scores the map merge nodelet's saved map (save_map: merged_poses.csv, submap_ids.csv) against
a dataset's ground truth, as DATASET.md's ATE (positions, best rigid alignment, no scale), over
all robots of each map frame and per robot (each aligned alone, odometry alone beside it); and,
when the dataset has stems.csv, its merged_stems.csv as dtif merge scores its own (each map
frame placed by its poses' alignment; a stem matches the nearest true one within 0.5 m): listed,
matched, precision, recall, duplicates, position and DBH errors.
With --false-loop (the CSV inject_false_loop.py wrote), it also says whether the loop injected
on purpose is in the saved pose graph (pose_graph.g2o holds the odometry edges and the loops
used; a loop the back end rejected is not there).
Usage: score_ros_merge.py <dataset_dir> <map_dir> [--false-loop loop.csv]"""
import argparse
import csv
import math
import os
import sys


def best_rotation(h):
    """Unit quaternion (w, x, y, z) of the rotation R maximising sum g . R e, from the
    cross-covariance h[i][j] = sum e_i g_j (Horn 1987): the top eigenvector of a symmetric 4x4
    matrix."""
    (sxx, sxy, sxz), (syx, syy, syz), (szx, szy, szz) = h
    n = [[sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
         [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
         [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
         [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz]]
    return top_eigenvector(n)


def top_eigenvector(a):
    """Eigenvector of the largest eigenvalue of a symmetric matrix (cyclic Jacobi rotations)."""
    k = len(a)
    a = [row[:] for row in a]
    v = [[float(i == j) for j in range(k)] for i in range(k)]
    for _ in range(100):
        off = sum(a[i][j] ** 2 for i in range(k) for j in range(k) if i != j)
        if off < 1e-30:
            break
        for p in range(k):
            for q in range(p + 1, k):
                if abs(a[p][q]) < 1e-300:
                    continue
                theta = (a[q][q] - a[p][p]) / (2 * a[p][q])
                t = math.copysign(1.0, theta) / (abs(theta) + math.sqrt(theta * theta + 1))
                c = 1 / math.sqrt(t * t + 1)
                s = t * c
                for r in range(k):  # A <- A J
                    arp, arq = a[r][p], a[r][q]
                    a[r][p], a[r][q] = c * arp - s * arq, s * arp + c * arq
                for r in range(k):  # A <- J^T A
                    apr, aqr = a[p][r], a[q][r]
                    a[p][r], a[q][r] = c * apr - s * aqr, s * apr + c * aqr
                for r in range(k):
                    vrp, vrq = v[r][p], v[r][q]
                    v[r][p], v[r][q] = c * vrp - s * vrq, s * vrp + c * vrq
    best = max(range(k), key=lambda i: a[i][i])
    return [v[r][best] for r in range(k)]


def rotate(q, v):
    w, x, y, z = q
    t = [2 * (y * v[2] - z * v[1]), 2 * (z * v[0] - x * v[2]), 2 * (x * v[1] - y * v[0])]
    return [v[0] + w * t[0] + y * t[2] - z * t[1], v[1] + w * t[1] + z * t[0] - x * t[2],
            v[2] + w * t[2] + x * t[1] - y * t[0]]


def align(est, gt):
    """The rigid transform (no scale) that best maps est onto gt: p -> R (p - ce) + cg."""
    n = len(est)
    ce = [sum(p[i] for p in est) / n for i in range(3)]
    cg = [sum(p[i] for p in gt) / n for i in range(3)]
    h = [[sum((e[i] - ce[i]) * (g[j] - cg[j]) for e, g in zip(est, gt)) for j in range(3)]
         for i in range(3)]
    q = best_rotation(h)
    return lambda p: [r + c for r, c in zip(rotate(q, [p[i] - ce[i] for i in range(3)]), cg)]


def align_rms(est, gt):
    """RMS residual [m] after the rigid transform (no scale) that best maps est onto gt."""
    t = align(est, gt)
    sq = sum(sum((a - b) ** 2 for a, b in zip(t(e), g)) for e, g in zip(est, gt))
    return math.sqrt(sq / len(est))


def median(v):
    v = sorted(v)
    h = len(v) // 2
    return v[h] if len(v) % 2 else 0.5 * (v[h - 1] + v[h])


def score_stems(ds, mp, by_comp, gt):
    """The saved inventory as dtif merge's scoreStems scores its own (match radius 0.5 m, over
    the map frames with poses): a dict of listed, matched, precision, recall (true stems within
    10 m of a submap's ground-truth position that some entry matched), duplicates (entries
    beyond the first on one true stem; rate per matched entry), mean position error [m] and
    median |DBH error| [m]. gt: the submaps' ground-truth positions (ground_truth.csv) by id."""
    true = [[float(r[k]) for k in ("x", "y", "dbh")] for r in csv.DictReader(open(ds + "/stems.csv"))]
    place = {c: align([r[0] for r in rows], [r[1] for r in rows]) for c, rows in by_comp.items()}
    pos, dbh, hits, listed = [], [], [0] * len(true), 0
    for r in csv.DictReader(open(mp + "/merged_stems.csv")):
        if r["component"] not in place:
            continue
        listed += 1
        p = place[r["component"]]([float(r[k]) for k in ("x", "y", "z_base")])
        d, j = min((math.hypot(p[0] - t[0], p[1] - t[1]), j) for j, t in enumerate(true))
        if d < 0.5:
            pos.append(d)
            dbh.append(abs(float(r["dbh"]) - true[j][2]))
            hits[j] += 1
    in_range = [j for j, t in enumerate(true)
                if any(math.hypot(t[0] - q[0], t[1] - q[1]) <= 10.0 for q in gt.values())]
    matched = len(pos)
    duplicates = sum(h - 1 for h in hits if h > 1)
    return {"listed": listed, "matched": matched,
            "precision": matched / listed if listed else 0.0,
            "recall": sum(1 for j in in_range if hits[j]) / len(in_range) if in_range else 0.0,
            "duplicates": duplicates, "duplicate_rate": duplicates / matched if matched else 0.0,
            "pos": sum(pos) / max(matched, 1), "dbh": median(dbh) if dbh else 0.0}


def false_loop_verdict(mp, loop_csv):
    """'used' when the saved pose graph has an edge between the false loop's two submaps,
    else 'rejected'."""
    loop = next(csv.DictReader(open(loop_csv)))
    gid = {(r["robot"], r["submap_id"]): r["id"] for r in csv.DictReader(open(mp + "/submap_ids.csv"))}
    q = gid.get((loop["query_robot"], loop["query_id"]))
    c = gid.get((loop["candidate_robot"], loop["candidate_id"]))
    if q is None or c is None:
        sys.exit("score_ros_merge.py: %s: a submap of the false loop is not in %s/submap_ids.csv"
                 % (loop_csv, mp))
    edges = {frozenset(line.split()[1:3]) for line in open(mp + "/pose_graph.g2o")
             if line.startswith("EDGE")}
    return "%s/%s -> %s/%s: %s" % (loop["query_robot"], loop["query_id"], loop["candidate_robot"],
                                   loop["candidate_id"],
                                   "USED (in the pose graph)" if frozenset((q, c)) in edges
                                   else "rejected (not in the pose graph)")


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("dataset")
    p.add_argument("map")
    p.add_argument("--false-loop", default="", help="inject_false_loop.py's CSV of the loop")
    args = p.parse_args()
    ds, mp = args.dataset, args.map
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
    if os.path.exists(ds + "/stems.csv") and os.path.exists(mp + "/merged_stems.csv"):
        st = score_stems(ds, mp, by_comp, gt)
        print("stems listed  matched  precision  recall  duplicates  mean position error [m]  "
              "median DBH error [cm]")
        print("%12d  %7d  %9.3f  %6.3f  %4d (%.1f %%)  %23.3f  %21.2f" % (
            st["listed"], st["matched"], st["precision"], st["recall"], st["duplicates"],
            100 * st["duplicate_rate"], st["pos"], 100 * st["dbh"]))
    if args.false_loop:
        print("false loop " + false_loop_verdict(mp, args.false_loop))


if __name__ == "__main__":
    main()

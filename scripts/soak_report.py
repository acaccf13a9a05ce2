#!/usr/bin/python3
"""Verdicts and plots of a soak run (scripts/soak.sh writes the inputs into its run folder).

Accounting (every item must hold):
  - per robot, the descriptors the unit published = the dataset's submaps of that robot whose
    window ended within the played bag time; ids without gaps (none dropped by extraction);
  - every valid descriptor published was queried (a loop-log row) and is in the database
    (database_size); invalid ones are neither (by design);
  - every accepted query in the loop log was published on /loop_closures and reached the map
    merge (loops_used + loops_rejected of get_map_info).
Memory: a process levels off when its RSS grew, from the middle of the run to its end, by no
more than --level-mb (16 MB). The base station's grows with its database by design: it levels
off when its RSS at the end is within max(--level-mb, --reload-frac (15 %)) of a fresh base
station that loaded the run's saved database (soak_reload.sh, reload.csv): memory beyond the
database's own is what an hour of queries left behind. File descriptors and threads of dtif's
processes: at most 2 more at the end than in the middle (the base station's solver libraries
start a thread pool once, in the first minute, when the map merge still factors the graph).
Lag (a result's time minus its submap's last cloud's), in wall time and in bag (ROS) time; the
verdict: wall-time max < --max-lag-s (at rate 1, as on a unit, the two are the same).
Also compares the loops with dtif eval's on the same dataset (reported, not a verdict: the order
in which robots' descriptors reach the database differs online).
Writes rss.png, lag.png, summary.md, summary.json into --run; exit 1 when a verdict fails.
"""
import argparse
import bisect
import csv
import json
import math
import os
import re
import sys
from collections import defaultdict

import matplotlib
import yaml

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def percentile(values, q):
    if not values:
        return float("nan")
    v = sorted(values)
    return v[min(len(v) - 1, int(math.ceil(q / 100.0 * len(v))) - 1 if q > 0 else 0)]


def yaml_value(path, key):
    """A field of `rosservice call`'s YAML output, None when the call failed or lacks it."""
    try:
        with open(path) as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError):
        return None
    return doc.get(key) if isinstance(doc, dict) else None


class Report:
    def __init__(self, a):
        self.a = a
        self.lines = []
        self.failures = []
        self.data = {}

    def say(self, text=""):
        print(text)
        self.lines.append(text)

    def check(self, ok, what):
        if not ok:
            self.failures.append(what)
            self.say("  FAIL: " + what)
        return ok

    # ---- descriptors ----
    def descriptors(self, window_s):
        a = self.a
        end = a.bag_start + a.played_s
        expected = defaultdict(list)  # robot -> dataset stamps of windows that ended in time
        for r in rows(os.path.join(a.dataset, "submaps.csv")):
            if float(r["stamp"]) + window_s / 2 <= end + 1e-6:
                expected[r["robot"]].append(float(r["stamp"]))
        published = defaultdict(list)
        for r in rows(os.path.join(a.run, "descriptors.csv")):
            published[r["robot"]].append(r)
        log = rows(os.path.join(a.run, "loops.csv"))
        queried = defaultdict(set)
        for r in log:
            queried[r["query_robot"]].add(int(r["query_id"]))
        db_robots = yaml_value(os.path.join(a.run, "database_size.yaml"), "robots") or []
        db_counts = yaml_value(os.path.join(a.run, "database_size.yaml"), "per_robot") or []
        in_db = dict(zip(db_robots, (int(x) for x in db_counts)))
        self.say("## Descriptors (per robot)")
        self.say("")
        self.say("| robot | submaps in the bag | published | id gaps | valid | queried | "
                 "in the database |")
        self.say("|---|---|---|---|---|---|---|")
        totals = defaultdict(int)
        problems = []
        for robot in sorted(set(expected) | set(published)):
            pub = published[robot]
            ids = sorted(int(r["submap_id"]) for r in pub)
            gaps = (ids[-1] + 1 - len(set(ids))) if ids else 0
            dups = len(ids) - len(set(ids))
            valid = {int(r["submap_id"]) for r in pub if r["valid"] == "1"}
            n_db = in_db.get(robot, 0)
            row = (robot, len(expected[robot]), len(pub), gaps, len(valid), len(queried[robot]),
                   n_db)
            self.say("| %s | %d | %d | %d | %d | %d | %d |" % row)
            for k, v in zip(("bag", "published", "gaps", "valid", "queried", "db"), row[1:]):
                totals[k] += v
            if len(pub) != len(expected[robot]):
                problems.append("%s: %d descriptors published for %d submaps in the bag"
                                % (robot, len(pub), len(expected[robot])))
            if gaps or dups:
                problems.append("%s: %d submap ids missing, %d twice" % (robot, gaps, dups))
            if queried[robot] != valid:
                problems.append("%s: %d valid descriptors not queried, %d queried not seen valid"
                                % (robot, len(valid - queried[robot]), len(queried[robot] - valid)))
            if n_db != len(valid):
                problems.append("%s: %d in the database for %d valid" % (robot, n_db, len(valid)))
        self.say("| all | %(bag)d | %(published)d | %(gaps)d | %(valid)d | %(queried)d | %(db)d |"
                 % totals)
        self.say("")
        for p in problems:
            self.check(False, p)
        if not problems:
            self.say("Every submap of the bag gave a descriptor; every valid one was queried and "
                     "is in the database.")
        self.data["descriptors"] = dict(totals)
        return log

    # ---- loops ----
    def loops(self, log):
        a = self.a
        accepted = [r for r in log if r["accepted"] in ("1", "true")]
        # Inter-robot loops beside a query's best one reach the merge but not the loop log.
        all_received = rows(os.path.join(a.run, "loop_msgs.csv"))
        received = [r for r in all_received if r.get("inter_robot_extra", "0") != "1"]
        used = yaml_value(os.path.join(a.run, "map_info.yaml"), "loops_used")
        rejected = yaml_value(os.path.join(a.run, "map_info.yaml"), "loops_rejected")
        merge = int(used) + int(rejected) if used is not None and rejected is not None else -1
        self.say("## Loops")
        self.say("")
        self.say("- queries %d, accepted %d (loop log); published on /loop_closures %d; "
                 "map merge: %s used + %s rejected = %d" % (len(log), len(accepted),
                                                            len(received), used, rejected, merge))
        key = lambda r: (r["query_robot"], r["query_id"], r["candidate_robot"], r["candidate_id"])
        self.check(sorted(map(key, accepted)) == sorted(map(key, received)),
                   "loops in the log and on /loop_closures differ")
        if merge < 0:
            self.check(False, "the map merge did not answer get_map_info (map_info.yaml: busy "
                       "beyond the call's time limit?): its loops are unaccounted for")
        else:
            self.check(merge == len(all_received),
                       "the map merge holds %d loops of %d published" % (merge, len(all_received)))
        score = json.load(open(os.path.join(a.run, "score", "summary.json")))
        ev = json.load(open(os.path.join(a.eval, "summary.json")))
        txt = open(os.path.join(a.run, "score.txt")).read()
        m = re.search(r"same loops as dtif eval: (\d+) of (\d+) online loops have eval's "
                      r"candidate; of eval's (\d+) loops, (\d+) not found online", txt)
        tp = score.get("true_positives", score.get("tp"))
        self.say("- against ground truth (dtif score): %s accepted, precision %s, recall %s"
                 % (score.get("accepted"), score.get("precision"), score.get("recall")))
        self.say("- dtif eval on the same dataset (all of it, offline): %s accepted, precision %s"
                 % (ev.get("accepted"), ev.get("precision")))
        if m:
            self.say("- online loops with eval's candidate: %s of %s; eval's loops not found "
                     "online: %s of %s (%s)" % (m.group(1), m.group(2), m.group(4), m.group(3),
                                                "the bag was played in part"
                                                if self.a.partial else "whole bag"))
        self.say("")
        self.data["loops"] = {"queries": len(log), "accepted": len(accepted),
                              "published": len(received), "merge": merge,
                              "precision": score.get("precision"), "tp": tp,
                              "eval_accepted": ev.get("accepted")}

    # ---- memory ----
    def memory(self, log):
        a = self.a
        # Samples until the last result (the service calls and the shutdown afterwards open
        # connections of their own).
        last_wall = max(float(r["wall_time"]) for r in log) + 1.5 * a.period_s if log else 1e30
        procs = defaultdict(list)  # name -> [(bag_s, rss_mb, fds, threads, hwm_mb)]
        for r in rows(os.path.join(a.run, "procs.csv")):
            t = float(r["ros_time"]) - a.bag_start
            if float(r["wall_time"]) <= last_wall:
                procs[r["process"]].append((t, int(r["rss_kb"]) / 1024.0, int(r["fds"]),
                                            int(r["threads"]), int(r["hwm_kb"]) / 1024.0))
        # Database entries over bag time (one per valid query) and bytes per entry of its file.
        q_times = sorted(float(r["ros_time"]) - a.bag_start for r in log)
        size = yaml_value(os.path.join(a.run, "save_database.yaml"), "size")
        db_file = os.path.join(a.run, "database.bin")
        per_entry = (os.path.getsize(db_file) / float(size)
                     if size and int(size) > 0 and os.path.exists(db_file) else 0.0)
        self.say("## Memory (RSS, MB) at 25/50/75/100 % of the played bag time")
        self.say("")
        self.say("| process | 25 % | 50 % | 75 % | 100 % | peak (VmHWM) | growth 2nd half | "
                 "fds (mid/end) | threads (mid/end) |")
        self.say("|---|---|---|---|---|---|---|---|---|")
        mem = {}
        for name in sorted(procs, key=lambda n: ("manager" not in n, n)):
            s = procs[name]
            if len(s) < 8:
                continue
            at = lambda f: min(s, key=lambda x: abs(x[0] - f * a.played_s))
            # The end: the last sample while the bag played (when it stops, the player's
            # connections close and each node's input watch starts warning).
            playing = [x for x in s if x[0] < a.played_s - 0.5]
            mid, end = at(0.5), (playing or s)[-1]
            growth = end[1] - mid[1]
            peak = max(x[4] for x in s)
            self.say("| %s | %.0f | %.0f | %.0f | %.0f | %.0f | %+.1f | %d/%d | %d/%d |"
                     % (name, at(0.25)[1], mid[1], at(0.75)[1], end[1], peak, growth,
                        mid[2], end[2], mid[3], end[3]))
            dtif_proc = "manager" in name or name.endswith(("trunk_extraction", "loop_closure",
                                                            "map_merge"))
            if name != "dtif_manager":  # the base station's memory grows with its database
                self.check(growth <= a.level_mb, "%s: RSS grew %.1f MB in the 2nd half (limit "
                           "%.0f MB)" % (name, growth, a.level_mb))
            if dtif_proc:
                self.check(end[3] <= mid[3] + 2, "%s: threads %d -> %d" % (name, mid[3], end[3]))
            if dtif_proc:
                self.check(end[2] <= mid[2] + 2, "%s: open file descriptors %d -> %d"
                           % (name, mid[2], end[2]))
            mem[name] = {"rss_mb": [at(f)[1] for f in (0.25, 0.5, 0.75)] + [end[1]],
                         "peak_mb": peak, "growth_mb": growth}
        self.say("")
        self.database_memory(procs.get("dtif_manager", []), q_times, per_entry)
        self.data["memory"] = mem
        self.plot_rss(procs, q_times)

    def database_memory(self, s, q_times, per_entry):
        """The base station's RSS at the end of the run against a fresh base station holding the
        same database (soak_reload.sh: reload.csv): the difference is what the run left behind;
        and its RSS per database entry over the run."""
        a = self.a
        if len(s) < 8:
            self.check(False, "too few memory samples of dtif_manager")
            return
        end_mb = sum(x[1] for x in s[-3:]) / 3  # after the last result: the whole database
        reload_path = os.path.join(a.run, "reload.csv")
        if not os.path.exists(reload_path):
            self.check(False, "no reload.csv (soak_reload.sh): the database's own memory unknown")
            return
        reload = rows(reload_path)
        reload_mb = sum(int(r["rss_kb"]) for r in reload) / 1024.0 / len(reload)
        reload_threads = max(int(r["threads"]) for r in reload)
        limit = reload_mb + max(a.level_mb, a.reload_frac * reload_mb)

        def point(f):  # (entries, mean RSS of the samples within 2 % of the played time)
            near = [x for x in s if abs(x[0] - f * a.played_s) <= 0.02 * a.played_s]
            near = near or [min(s, key=lambda x: abs(x[0] - f * a.played_s))]
            return bisect.bisect_right(q_times, f * a.played_s), sum(x[1] for x in near) / len(near)

        (e1, m1), (e2, m2) = point(0.25), point(0.5)
        e3 = len(q_times)
        k1 = (m2 - m1) * 1024 / max(e2 - e1, 1)  # kB per entry
        k2 = (end_mb - m2) * 1024 / max(e3 - e2, 1)
        self.say("Base station (dtif_manager: loop closure + map merge, the database's owner): "
                 "%.0f MB after the run's %d entries; a fresh base station loading the saved "
                 "database (and solving its map) takes %.0f MB: the run left %+.1f MB behind "
                 "(limit %.1f MB: %.0f MB or %.0f %%, whichever is larger). Its RSS grew %.1f kB "
                 "per entry from 25 to 50 %% of the run and %.1f kB per entry from 50 to 100 %%; "
                 "the database file holds %.1f kB per entry."
                 % (end_mb, e3, reload_mb, end_mb - reload_mb, limit - reload_mb, a.level_mb,
                    100 * a.reload_frac, k1, k2, per_entry / 1024))
        self.say("")
        self.check(end_mb <= limit, "dtif_manager: %.0f MB at the end, %.0f MB for its database "
                   "reloaded (limit %.0f MB)" % (end_mb, reload_mb, limit))
        # Threads are checked from the middle to the end like every process's: a reload solves
        # its whole map with conjugate gradients at once, while the run factors with CHOLMOD
        # while the graph is small, whose library thread pool (3 threads, created once) stays.
        self.say("Threads: %d at the end, %d in the base station that reloaded the database."
                 % (s[-1][3], reload_threads))
        self.say("")
        self.data["database"] = {"end_mb": end_mb, "reload_mb": reload_mb,
                                 "kb_per_entry_first": k1, "kb_per_entry_second": k2,
                                 "file_kb_per_entry": per_entry / 1024, "entries": e3,
                                 "reload_threads": reload_threads}

    def plot_rss(self, procs, q_times):
        fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True,
                                      gridspec_kw={"height_ratios": [3, 1]})
        for name in sorted(procs):
            s = [x for x in procs[name] if x[0] >= 0]  # before the first message: no clock yet
            if not s or max(x[1] for x in s) < 20:  # loaders, rosout, player: small, listed in the table
                continue
            ax.plot([x[0] / 60 for x in s], [x[1] for x in s], label=name, lw=1.2)
        ax.set_ylabel("resident memory (VmRSS) [MB]")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        ax.set_title("soak: 6 units at %gx, RSS per process over bag time" % self.a.rate)
        ax2.plot([t / 60 for t in q_times], range(1, len(q_times) + 1), color="k", lw=1)
        ax2.set_ylabel("database entries")
        ax2.set_xlabel("bag time [min]")
        ax2.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(os.path.join(self.a.run, "rss.png"), dpi=110)
        plt.close(fig)

    # ---- lag ----
    def clock(self, log):
        """ROS time -> wall time while the bag played, from the (ROS, wall) pairs of the loop log
        and of the monitor's samples (piecewise linear; the bag's clock only moves forwards)."""
        pairs = [(float(r["ros_time"]), float(r["wall_time"])) for r in log]
        pairs += [(float(r["ros_time"]), float(r["wall_time"]))
                  for r in rows(os.path.join(self.a.run, "procs.csv"))]
        pairs = sorted(p for p in pairs if p[0] > self.a.bag_start)
        ros, wall = [], []
        for r, w in pairs:  # one wall time per ROS time: the earliest
            if not ros or r > ros[-1]:
                ros.append(r)
                wall.append(w)

        def wall_at(t):
            i = min(max(bisect.bisect_left(ros, t), 1), len(ros) - 1)
            f = (t - ros[i - 1]) / (ros[i] - ros[i - 1])
            return wall[i - 1] + f * (wall[i] - wall[i - 1])

        return wall_at

    def lag(self, log):
        a = self.a
        wall_at = self.clock(log)
        # (bag time of the last cloud, lag in bag time, lag in wall time, accepted)
        lag = [(float(r["query_data_end"]) - a.bag_start,
                float(r["ros_time"]) - float(r["query_data_end"]),
                float(r["wall_time"]) - wall_at(float(r["query_data_end"])),
                r["accepted"] in ("1", "true")) for r in log]
        self.say("## Lag (from a submap's last cloud to its loop-closure result)")
        self.say("")
        stats = {}
        for i, what in ((2, "wall time"), (1, "bag time (ROS time)")):
            v = [x[i] for x in lag]
            half = [x[i] for x in lag if x[0] >= a.played_s / 2]
            st = {"p50": percentile(v, 50), "p95": percentile(v, 95), "max": max(v or [0]),
                  "max_2nd_half": max(half or [0])}
            stats["wall" if i == 2 else "bag"] = st
            self.say("- in %s: p50 %.3f s, p95 %.3f s, max %.3f s over %d queries (2nd half: max "
                     "%.3f s)" % (what, st["p50"], st["p95"], st["max"], len(v),
                                  st["max_2nd_half"]))
        self.say("- the verdict is on wall time (limit %.1f s): a unit runs at rate 1, where the "
                 "two are the same; at rate %g a second of processing is %g s of bag time"
                 % (a.max_lag_s, a.rate, a.rate))
        self.say("")
        mx = stats["wall"]["max"]
        self.check(mx < a.max_lag_s, "lag reached %.3f s of wall time (limit %.1f s)"
                   % (mx, a.max_lag_s))
        self.data["lag_s"] = stats
        self.plot_lag(lag, stats)

    def plot_lag(self, lag, stats):
        a = self.a
        fig, ax = plt.subplots(figsize=(8, 4))
        for acc, color, label in ((False, "tab:blue", "query, no loop"),
                                  (True, "tab:red", "accepted loop")):
            pts = [x for x in lag if x[3] == acc]
            ax.scatter([x[0] / 60 for x in pts], [x[2] for x in pts], s=4, color=color,
                       label=label, alpha=0.6)
        ax.axhline(a.max_lag_s, color="k", ls="--", lw=1, label="limit")
        ax.set_xlabel("bag time of the submap's last cloud [min]")
        ax.set_ylabel("lag [s of wall time]")
        ax.set_title("soak: lag of each loop-closure result at rate %g (wall p50 %.2f s, p95 %.2f "
                     "s, max %.2f s; in bag time x%g)" % (a.rate, stats["wall"]["p50"],
                                                          stats["wall"]["p95"],
                                                          stats["wall"]["max"], a.rate),
                     fontsize=9)
        ax.set_ylim(bottom=0)
        sec = ax.secondary_yaxis("right", functions=(lambda y: y * a.rate, lambda y: y / a.rate))
        sec.set_ylabel("[s of bag time]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(os.path.join(a.run, "lag.png"), dpi=110)
        plt.close(fig)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--dataset", required=True)
    p.add_argument("--eval", required=True)
    p.add_argument("--run", required=True)
    p.add_argument("--bag-start", type=float, required=True)
    p.add_argument("--played-s", type=float, required=True)
    p.add_argument("--bag-s", type=float, default=0.0, help="the whole bag's duration")
    p.add_argument("--rate", type=float, default=5.0)
    p.add_argument("--window-s", type=float, default=10.0)
    p.add_argument("--max-lag-s", type=float, default=1.0)
    p.add_argument("--period-s", type=float, default=5.0, help="the monitor's sampling period")
    p.add_argument("--level-mb", type=float, default=16.0,
                   help="RSS growth allowed in the 2nd half (processes without the database)")
    p.add_argument("--reload-frac", type=float, default=0.15,
                   help="base station: RSS beyond its reloaded database's allowed, as a fraction "
                   "(or --level-mb, whichever is larger)")
    a = p.parse_args()
    a.partial = a.bag_s > 0 and a.played_s < a.bag_s - 1
    r = Report(a)
    log = r.descriptors(a.window_s)
    r.loops(log)
    r.memory(log)
    r.lag(log)
    r.say("## Verdict")
    r.say("")
    r.say("PASS" if not r.failures else "FAIL: " + "; ".join(r.failures))
    r.data["failures"] = r.failures
    with open(os.path.join(a.run, "summary.md"), "w") as f:
        f.write("\n".join(r.lines) + "\n")
    with open(os.path.join(a.run, "summary.json"), "w") as f:
        json.dump(r.data, f, indent=1)
    return 1 if r.failures else 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""Injects one false loop closure into a running fleet, through the topic the map merge nodelet
reads (/loop_closures), as `dtif merge --inject-false-loop` does offline: the robustness check
of the merge back end through the nodelets (scripts/demo.sh with DTIF_DEMO_FALSE_LOOP=1).

Once --after loops have arrived on the topic and one of them joined two robots, it publishes a
loop between those robots' two submaps farthest apart on the map merge's paths (its latest
/map_merge/path/<robot>; submaps known by their descriptors' stamps; robots not joined yet: the
candidate robot's first submap and the query robot's latest), query the later one, with
the wrong transform dtif merge gives its false loop (3 m, -2 m, a 0.4 rad turn: what an aliased
trunk pattern gives), the first loop's covariance and the most inliers any loop had. It writes
the loop it published to --out (CSV: query_robot,query_id,candidate_robot,candidate_id) and
exits; score_ros_merge.py --false-loop reads that file and the saved pose graph and says whether
the back end used it.
Usage: inject_false_loop.py --robots alpha bravo [--after N] [--out loop.csv]
                            [--loop-topic /loop_closures] [--map-ns /map_merge]"""
import argparse
import math
import sys
import threading
import time

import rospy
from nav_msgs.msg import Path

from dtif.msg import LoopClosure, TrunkDescriptor


def ms(stamp):
    """A stamp in whole milliseconds: the paths carry the submaps' stamps as doubles."""
    return round(stamp.to_nsec() / 1e6)


class Injector:
    def __init__(self, args):
        self.args = args
        self.submaps = {}  # robot -> {stamp [ms]: (submap_id, odometry frame)}
        self.paths = {}  # robot -> latest nav_msgs/Path
        self.loops = []  # loops seen on the topic, in order
        self.sent = None
        self.lock = threading.Lock()  # callbacks run on several threads
        self.pub = rospy.Publisher(args.loop_topic, LoopClosure, queue_size=10, latch=True)
        self.subs = [rospy.Subscriber(args.loop_topic, LoopClosure, self.on_loop, queue_size=100)]
        for r in args.robots:
            self.submaps[r] = {}
            self.subs.append(rospy.Subscriber("/%s/descriptor" % r, TrunkDescriptor,
                                              self.on_descriptor, r, queue_size=100))
            self.subs.append(rospy.Subscriber("%s/path/%s" % (args.map_ns, r), Path,
                                              self.on_path, r, queue_size=2))

    def on_descriptor(self, msg, robot):
        with self.lock:
            self.submaps[robot][ms(msg.header.stamp)] = (msg.submap_id, msg.header.frame_id)

    def on_path(self, msg, robot):
        with self.lock:
            self.paths[robot] = msg

    def on_loop(self, msg):
        with self.lock:
            if self.sent is not None:  # done (our own loop comes back too)
                return
            self.loops.append(msg)
            linked = [l for l in self.loops if l.query_robot != l.candidate_robot]
            if len(self.loops) >= self.args.after and linked:
                self.send(linked[0])

    def positions(self, robot):
        """(stamp [ms], submap id, position, map frame) of the robot's submaps on its path."""
        path = self.paths.get(robot)
        if path is None:
            return []
        out = []
        for p in path.poses:
            known = self.submaps[robot].get(ms(p.header.stamp))
            if known is not None:
                q = p.pose.position
                out.append((ms(p.header.stamp), known[0], (q.x, q.y, q.z),
                            path.header.frame_id))
        return out

    def farthest_pair(self, ra, rb):
        """(candidate submap of ra, query submap of rb), the query later, farthest apart on the
        map; without paths in one frame: ra's first submap and rb's latest."""
        best, best_d = None, -1.0
        queries = self.positions(rb)
        for c in self.positions(ra):
            for q in queries:
                if q[0] <= c[0] or q[3] != c[3]:
                    continue
                d = math.dist(c[2], q[2])
                if d > best_d:
                    best, best_d = (c[0], q[0]), d
        if best is None:
            if not self.submaps[ra] or not self.submaps[rb]:
                return None
            best = (min(self.submaps[ra]), max(self.submaps[rb]))
            best_d = float("nan")
        return best, best_d

    def send(self, first):
        ra, rb = first.candidate_robot, first.query_robot
        found = self.farthest_pair(ra, rb)
        if found is None:
            return
        (c_ms, q_ms), dist = found
        c_id, c_frame = self.submaps[ra][c_ms]
        q_id, _ = self.submaps[rb][q_ms]
        m = LoopClosure()
        m.header.stamp = rospy.Time(nsecs=q_ms * 1000000)
        m.header.frame_id = c_frame
        m.query_robot, m.query_id = rb, q_id
        m.candidate_robot, m.candidate_id = ra, c_id
        m.T_c_q.position.x, m.T_c_q.position.y, m.T_c_q.position.z = 3.0, -2.0, 0.0
        m.T_c_q.orientation.z, m.T_c_q.orientation.w = math.sin(0.2), math.cos(0.2)
        m.covariance = first.covariance
        m.inliers = max(12, max(l.inliers for l in self.loops))
        m.score = 0.9
        self.sent = m
        self.pub.publish(m)
        where = ("%.1f m apart on the map" % dist if not math.isnan(dist)
                 else "not yet in one map frame: the first and the latest submap")
        rospy.loginfo("false loop after %d loops: %s/%d -> %s/%d (%s), T_c_q 3 m, -2 m, 0.4 rad",
                      len(self.loops), rb, q_id, ra, c_id, where)
        if self.args.out:
            with open(self.args.out, "w") as f:
                f.write("query_robot,query_id,candidate_robot,candidate_id\n")
                f.write("%s,%d,%s,%d\n" % (rb, q_id, ra, c_id))


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--robots", nargs="+", required=True)
    p.add_argument("--after", type=int, default=1, help="loops to wait for first (default 1)")
    p.add_argument("--out", default="", help="CSV of the loop published")
    p.add_argument("--loop-topic", default="/loop_closures")
    p.add_argument("--map-ns", default="/map_merge")
    args = p.parse_args(rospy.myargv(sys.argv)[1:])
    if args.after < 1:
        p.error("--after must be at least 1")
    rospy.init_node("inject_false_loop", anonymous=True)
    inj = Injector(args)
    # Wall time: the bag's clock stops when it ends.
    while not rospy.is_shutdown() and inj.sent is None:
        time.sleep(0.2)
    time.sleep(2.0)  # the latched message reaches the map merge before this node goes


if __name__ == "__main__":
    main()

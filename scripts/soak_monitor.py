#!/usr/bin/python3
"""The soak test's observer (scripts/soak.sh starts it; a ROS node, run with use_sim_time).

Records, until shut down (SIGINT):
  descriptors.csv  every descriptor each unit published (/<robot>/descriptor), as received;
  loop_msgs.csv    every loop closure the base station published (/loop_closures);
  procs.csv        every --period s of wall time, for each process descending from --root
                   (roslaunch, rosmaster, rosout, the nodelet managers and loaders, rosbag's
                   player): resident memory (VmRSS, VmHWM), open file descriptors and threads
                   (with their names), from /proc/<pid>/.
Each row holds the ROS time (the bag's clock) and the wall time of the moment.
Usage: soak_monitor.py --out DIR --robots a,b,c --root PID [--period 5]
"""
import argparse
import os
import threading
import time
from collections import defaultdict

import rospy
from dtif.msg import LoopClosure, TrunkDescriptor


# Processes worth sampling: ROS nodes (named by __name:=) and these programs (argv[0] or, for a
# Python program, argv[1]); helpers such as sleep or rosservice calls are left out.
PROGRAMS = {'roslaunch', 'rosmaster', 'play'}


def proc_name(pid, argv):
    """The name a process is recorded under, or None when it is not one to sample."""
    names = [a[len('__name:='):] for a in argv if a.startswith('__name:=')]
    if names:  # roslaunch passes a node's namespace in its environment
        try:
            with open('/proc/%d/environ' % pid, 'rb') as f:
                env = dict(e.split('=', 1) for e in f.read().decode(errors='replace').split('\0')
                           if '=' in e)
        except OSError:
            env = {}
        ns = env.get('ROS_NAMESPACE', '').strip('/')
        return ns + '/' + names[0] if ns else names[0]
    prog = os.path.basename(argv[0])
    if prog.startswith('python') and len(argv) > 1:
        prog = os.path.basename(argv[1])
    return prog if prog in PROGRAMS else None


def descendants(root):
    """{pid: name} of root's descendant processes worth sampling (not this one)."""
    parent, argvs = {}, {}
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open('/proc/%s/stat' % entry) as f:
                parent[int(entry)] = int(f.read().rsplit(')', 1)[1].split()[1])
            with open('/proc/%s/cmdline' % entry, 'rb') as f:
                argvs[int(entry)] = f.read().decode(errors='replace').split('\0')
        except (OSError, IndexError, ValueError):
            parent.pop(int(entry), None)  # gone meanwhile
    found = {}
    for pid in argvs:
        p = pid
        while p in parent and p not in (root, 0, 1):
            p = parent[p]
        name = proc_name(pid, argvs[pid]) if p == root and pid != os.getpid() else None
        if name:
            found[pid] = name
    return found


def proc_sample(pid):
    """(rss_kb, hwm_kb, fds, threads, thread names) of a live process, else None."""
    try:
        fields = {}
        with open('/proc/%d/status' % pid) as f:
            for line in f:
                key, _, value = line.partition(':')
                fields[key] = value.split()
        fds = len(os.listdir('/proc/%d/fd' % pid))
        comms = defaultdict(int)  # thread name -> count, to tell which threads come and go
        for tid in os.listdir('/proc/%d/task' % pid):
            try:
                with open('/proc/%d/task/%s/comm' % (pid, tid)) as f:
                    comms[f.read().strip().replace(' ', '_')] += 1
            except OSError:
                pass
        names = ' '.join('%s*%d' % kv for kv in sorted(comms.items()))
        return (int(fields['VmRSS'][0]), int(fields['VmHWM'][0]), fds, int(fields['Threads'][0]),
                names)
    except (OSError, KeyError, IndexError, ValueError):
        return None


class Monitor:
    def __init__(self, args):
        self.args = args
        self.lock = threading.Lock()
        self.files = {}
        self.open('descriptors', 'robot,submap_id,stamp,data_end,valid,trunks,ros_time,wall_time')
        self.open('loop_msgs', 'query_robot,query_id,candidate_robot,candidate_id,inliers,'
                  'inter_robot_extra,ros_time,wall_time')
        self.open('procs', 'wall_time,ros_time,process,pid,rss_kb,hwm_kb,fds,threads,thread_names')
        self.subs = [rospy.Subscriber('/%s/descriptor' % r, TrunkDescriptor, self.on_descriptor,
                                      queue_size=1000) for r in args.robots.split(',')]
        self.subs.append(rospy.Subscriber('/loop_closures', LoopClosure, self.on_loop,
                                          queue_size=1000))

    def open(self, name, header):
        f = open(os.path.join(self.args.out, name + '.csv'), 'w')
        f.write(header + '\n')
        f.flush()
        self.files[name] = f

    def write(self, name, row):
        with self.lock:
            self.files[name].write(','.join(str(x) for x in row) + '\n')
            self.files[name].flush()  # the run may be stopped any time

    def now(self):
        return '%.3f' % rospy.get_time(), '%.3f' % time.time()

    def on_descriptor(self, m):
        self.write('descriptors', (m.robot, m.submap_id, '%.3f' % m.header.stamp.to_sec(),
                                   '%.3f' % m.data_end.to_sec(), int(m.valid), len(m.trunks))
                   + self.now())

    def on_loop(self, m):
        self.write('loop_msgs', (m.query_robot, m.query_id, m.candidate_robot, m.candidate_id,
                             m.inliers, int(m.inter_robot_extra)) + self.now())

    def sample(self):
        procs = descendants(self.args.root)
        ros_time, wall_time = self.now()
        for pid, name in sorted(procs.items(), key=lambda kv: kv[1]):
            s = proc_sample(pid)
            if s is not None:
                self.write('procs', (wall_time, ros_time, name, pid) + s)

    def run(self):
        while not rospy.is_shutdown():
            self.sample()
            time.sleep(self.args.period)  # wall time: the sampling goes on if the clock stalls


def main():
    p = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    p.add_argument('--out', required=True)
    p.add_argument('--robots', required=True, help='comma-separated robot names')
    p.add_argument('--root', type=int, required=True,
                   help="the pid whose descendants are sampled (soak.sh's own)")
    p.add_argument('--period', type=float, default=5.0, help='wall seconds between samples')
    args = p.parse_args(rospy.myargv()[1:])
    rospy.init_node('soak_monitor', disable_signals=False)
    Monitor(args).run()


if __name__ == '__main__':
    main()

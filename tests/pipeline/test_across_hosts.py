"""Across machines (issue #19): the node set on three hosts of its own, over real DDS, on a bad network.

Hosts are Linux network namespaces this module creates and removes (tests/support/netns.py):
    headset      play_node + tracking_node
    workstation  sim_node + record_node (the recording of every phase is made here)
    server       world_node
joined by a switch in a namespace of its own. Discovery is ROS's default SUBNET range (multicast
on the LAN, no configuration), ROS_DOMAIN_ID is the run's own. The node set is started once; four
phases each replay a sample bag and record it on the workstation:
    clean   grasp_lift, no impairment: the ball is lifted, every tracker frame and sim step recorded
    delay   grasp_short, 20 +- 5 ms on every host's uplink
    loss    grasp_short, 2 % of the packets of every host dropped
    outage  grasp_short, the workstation's switch port down for 1 s, then up
In each: no node dies, every recorded value is finite, no hole in the recording but the outage;
in the outage the hand holds its last target, tracks again within 2 s, the world and the sim
decouple the stale copies and recouple, and the gaps are counted in /diagnostics. Latency and
bytes per link per topic are measured and printed (pytest -s shows the table).

Nothing leaves the namespaces: a packet socket on the machine's own interfaces (this process's
namespace) counts every packet from or to the LAN's addresses or to the domain's DDS ports, and
must count none but the control packets this test sends itself.
"""
from __future__ import annotations

import json
import socket
import subprocess
import sys
import os
import time
from pathlib import Path

import numpy as np
import pytest

from softhand_sim.commands.demo import ProcessSet, console_script
from softhand_sim.commands.run_summary import summarize_run
from softhand_sim.paths import bags_dir
from softhand_sim.ros.env import isolated_env, pick_domain_id, release_domain_id
from softhand_sim.ros.msgs import status_node
from softhand_tracking.play_node import REPLAY_STARTED
from tests.support import netns

# timeout: the first test to run sets the hosts up and runs every phase (~3 min on 2 cores)
pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.timeout(900)]

REPO = Path(__file__).resolve().parents[2]
HOSTS = ("headset", "workstation", "server")
DIAG = ["-p", "diagnostics_rate:=4.0"]  # a status every 0.25 s: the outage shows in several
OUTAGE_AT, OUTAGE_S = 2.5, 1.0          # [s] after the first tracker frame; length of the link down
PHASES = (  # name, bag, impairment of every host's uplink
    ("clean", "grasp_lift", {}),
    ("delay", "grasp_short", {"delay_ms": 20.0, "jitter_ms": 5.0}),
    ("loss", "grasp_short", {"loss_percent": 2.0}),
    ("outage", "grasp_short", {}),
)
# Who receives each topic across the LAN: topic -> (publishing host, {host: remote reader processes}).
# DDS sends user data by unicast to each matched reader's participant, so a topic read by two
# processes on one host crosses that host's link twice.
ROUTES = {
    "/tracker/right/hand_joints": ("headset", {"workstation": 1}),      # record
    "/hand/right/intermediate_bones": ("headset", {"workstation": 2}),  # sim, record
    "/hand/right/bones": ("workstation", {"headset": 1}),               # tracking
    "/hand/object_states": ("workstation", {"server": 1}),              # world
    "/world/object_states": ("server", {"workstation": 2}),             # sim, record
    "/world/markers": ("server", {"workstation": 1}),                   # record
    "/diagnostics@headset": ("headset", {"workstation": 1}),            # record
    "/diagnostics@server": ("server", {"workstation": 1}),              # record
}
# What the workstation records: every topic crossing the LAN and the sim's state; not the skin
# (local to the workstation, 216 kB messages: the recorder would mostly wait for the disk and a
# core; the viewer measurement covers the skin topics).
RECORDED = ("/tracker/right/hand_joints", "/hand/right/intermediate_bones", "/hand/right/bones",
            "/hand/object_states", "/world/object_states", "/hand/contacts", "/world/markers", "/diagnostics")
MAX_HOLE_S = 0.3  # [s] a longer gap between the stamps of a periodic remote topic is a hole


# ------------------------------------------------------------------------------------ recording


def read_bag(bag_dir):
    """{topic: [(receive time [s], raw size [bytes], message)]} of a recording."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    out = {}
    with Reader(bag_dir) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t * 1e-9, len(raw), store.deserialize_cdr(raw, conn.msgtype)))
    return out


def stamp_s(msg):
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def palm(msg):
    p = msg.poses[0].position
    return np.array([p.x, p.y, p.z])


def diag_rows(bag, node):
    """[(header stamp [s], values dict)] of one node's /diagnostics, in stamp order."""
    rows = []
    for _t, _n, m in bag.get("/diagnostics", []):
        for st in m.status:
            if status_node(st.name) == node:
                rows.append((stamp_s(m), {kv.key: kv.value for kv in st.values}))
    return sorted(rows, key=lambda r: r[0])


def bag_frames(name):
    from rosbags.rosbag2 import Reader

    with Reader(bags_dir() / name) as r:
        return sum(c.msgcount for c in r.connections if c.topic == "/tracker/hand_joints")


def holes(times, skip=None, limit=MAX_HOLE_S):
    """Gaps longer than `limit` between consecutive (sorted) times, except those within `skip`.

    Given the publishers' header stamps (tracking_node stamps each scheduled step and runs the
    steps a stall missed, world_node stamps each engine step), a gap is a message published and
    not recorded; receive times would also count the stalls of a loaded machine."""
    t = np.sort(np.asarray(times))
    out = []
    for a, b in zip(t[:-1], t[1:]):
        if b - a > limit and not (skip and a >= skip[0] - limit and b <= skip[1] + 1.0):
            out.append((round(a, 3), round(b - a, 3)))
    return out


def latency(bag):
    """Tracker frame (published on the headset) -> /hand/right/bones (published on the workstation) [ms].

    The hosts share one clock (namespaces of one machine). The recording on the workstation has
    the receive time of each tracker frame and of each intermediate-bone message, both sent by the
    headset over the same path, and the header stamp (headset send time) of the latter: their
    one-way delay (network + the recorder's wait for a core). A frame received at t was
    published at t0 = t - median one-way; it is in the simulation once the first intermediate-bone
    message stamped after t0 has arrived and the next /hand/right/bones follows. Returns (e2e ms array,
    one-way ms array). On a loaded machine the low percentiles of the one-way delay show the
    network, the median mostly the processes' waits.
    """
    inter = bag["/hand/right/intermediate_bones"]
    i_recv = np.array([t for t, _, _ in inter])
    i_stamp = np.array([stamp_s(m) for _, _, m in inter])
    one_way = i_recv - i_stamp
    d = float(np.median(one_way))
    bones = np.array([t for t, _, _ in bag["/hand/right/bones"]])
    order = np.argsort(i_stamp)
    i_stamp, i_recv = i_stamp[order], i_recv[order]
    e2e = []
    for t, _, _ in bag["/tracker/right/hand_joints"]:
        t0 = t - d
        k = np.searchsorted(i_stamp, t0, side="right")
        if k >= len(i_stamp):
            continue
        arrive = i_recv[k]
        j = np.searchsorted(bones, arrive, side="right")
        if j < len(bones) and bones[0] <= t0:
            e2e.append(bones[j] - t0)
    return 1e3 * np.array(e2e), 1e3 * one_way


def topic_bytes(bag, t_span):
    """{topic: (messages/s, mean size [B], bytes/s)} over the phase; /diagnostics split by host."""
    host_of = {"tracking_node": "headset", "play_node": "headset", "world_node": "server",
               "sim_node": "workstation"}
    out = {}
    for topic, rows in bag.items():
        groups = {topic: rows}
        if topic == "/diagnostics":
            groups = {}
            for r in rows:
                hosts = {host_of.get(st.name, "?") for st in r[2].status}
                groups.setdefault(f"/diagnostics@{hosts.pop()}", []).append(r)
        for name, rs in groups.items():
            sizes = np.array([n for _, n, _ in rs], dtype=float)
            out[name] = (len(rs) / t_span, float(sizes.mean()), float(sizes.sum()) / t_span)
    return out


# -------------------------------------------------------------------------------------- the run


class HostSet:
    """The node set on the LAN: one ProcessSet per host, every process inside its namespace."""

    def __init__(self, lan, env, log_dir):
        self.lan = lan
        self.procs = {h: ProcessSet(env, Path(log_dir) / h) for h in HOSTS}

    def start(self, host, name, argv):
        return self.procs[host].start(name, self.lan.exec_argv(host, argv))

    def probe(self, host, args, timeout=120):
        env = dict(self.procs[host].env)
        r = subprocess.run(self.lan.exec_argv(host, [sys.executable, str(REPO / "tests/support/graph_probe.py"),
                                                     "--timeout", str(timeout), *args]),
                           env=env, capture_output=True, text=True, timeout=timeout + 30)
        assert r.returncode == 0, f"discovery from {host}: {r.stdout}{r.stderr[-2000:]}\n{self.tails()}"

    def dead(self):
        return {f"{h}/{n}": p.procs[n][0].returncode for h, p in self.procs.items() for n in p.procs
                if not n.startswith(("play", "record", "viewer")) and not p.alive(n)}

    def tails(self):
        return "\n".join(f"--- {h}/{n}\n{p.tail(n)}" for h, p in self.procs.items() for n in p.procs)

    def stop_all(self):
        return {f"{h}/{n}": c for h, p in self.procs.items() for n, c in p.stop_all().items()}


ECHO = ("import socket,sys\ns=socket.socket(socket.AF_INET,socket.SOCK_DGRAM);s.bind(('',9));s.settimeout(5)\n"
        "while True:\n    try:\n        d,a=s.recvfrom(64)\n    except OSError:\n        break\n    s.sendto(d,a)")
PING = ("import socket,sys,time,json\ns=socket.socket(socket.AF_INET,socket.SOCK_DGRAM);s.settimeout(0.5);rtt=[]\n"
        "for i in range(int(sys.argv[2])):\n    t=time.monotonic();s.sendto(b'%d'%i,(sys.argv[1],9))\n"
        "    try:\n        while s.recvfrom(64)[0]!=b'%d'%i: pass\n        rtt.append(1e3*(time.monotonic()-t))\n"
        "    except OSError:\n        pass\n    time.sleep(0.02)\nprint(json.dumps(rtt))")


def udp_rtt(lan, a="headset", b="workstation", n=40):
    """Round trip times [ms] of small UDP datagrams a -> b -> a: the network alone (the switch and
    its impairment), without the ROS processes' waits for a core. Lost probes are left out."""
    echo = subprocess.Popen(lan.exec_argv(b, [sys.executable, "-c", ECHO]))
    try:
        time.sleep(0.3)
        r = lan.run(a, [sys.executable, "-c", PING, lan.address[b], str(n)], timeout=60)
        return json.loads(r.stdout)
    finally:
        echo.kill()
        echo.wait()


def wait_replay_started(log_path, proc, timeout=60.0):
    """Until play_node logs that its first frame goes out (its waits for subscribers are over).
    Not the headset's traffic: the tracking node publishes its held target all along, so the
    uplink is busy before the replay begins (an outage timed from it once came before the first
    frame reached the workstation, and the hand held the previous phase's pose)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        if REPLAY_STARTED in Path(log_path).read_text(errors="replace"):
            return
        time.sleep(0.02)
    raise AssertionError(f"play_node never started its replay: {Path(log_path).read_text(errors='replace')[-2000:]}")


def run_phase(hs, lan, out, name, bag_name, impairment):
    """One bag through the hosts, recorded on the workstation; returns what the checks need."""
    lan.impair(**impairment)
    ws = hs.procs["workstation"]
    rec_name = f"record_{name}"
    hs.start("workstation", rec_name, [console_script("softhand-record"), "-o", str(out / name / "bag"),
                                       "--topics", *RECORDED, "--ros-args", "-p", "flush_period:=0.5"])
    # the recorder (workstation) must hear the headset's tracker before the first frame is sent
    hs.probe("workstation", ["--pub", "/hand/right/intermediate_bones", "/world/object_states",
                             "--sub", "/hand/right/bones:2", "/hand/object_states:2"], timeout=60)
    time.sleep(1.0)
    before = lan.switch_stats()
    t_start = time.time()
    play = hs.start("headset", f"play_{name}", [console_script("softhand-play"), str(bags_dir() / bag_name),
                                                "--wait-subscribers", "2"])
    outage = None
    if name == "outage":
        # the first frame goes out once both tracker subscribers match: count from then
        wait_replay_started(hs.procs["headset"].log_dir / f"play_{name}.log", play)
        time.sleep(OUTAGE_AT)
        t_down = time.time()
        lan.link_down("workstation")
        time.sleep(OUTAGE_S)
        lan.link_up("workstation")
        outage = (t_down, time.time())
    play.wait(timeout=120)
    rtt = udp_rtt(lan)
    time.sleep(1.0)  # the last frames travel through tracking -> sim -> world -> record
    after = lan.switch_stats()
    t_end = time.time()
    dead = hs.dead()
    code = ws.stop(rec_name)
    play_code = hs.procs["headset"].stop(f"play_{name}")
    return {"name": name, "bag_name": bag_name, "bag": out / name / "bag", "outage": outage, "span": t_end - t_start,
            "switch": {h: {k: after[h][k] - before[h][k] for k in after[h]} for h in HOSTS},
            "dead": dead, "record_code": code, "play_code": play_code, "t_start": t_start, "rtt": rtt}


VIEWER_TOPICS = ("/hand/right/skin_vertices", "/hand/right/skin_marker", "/hand/right/skin_mesh")


def measure_viewer(hs, lan, out, window=4.0):
    """A remote viewer on the headset subscribing the skin topics (a recorder stands in for it):
    the bytes/s its link carries (switch counters, minus the same link's traffic just before)
    and per topic (recorded sizes x rates). The sim steps on its last targets meanwhile."""
    a = lan.switch_stats()["headset"]["tx_bytes"]
    time.sleep(2.0)
    base = (lan.switch_stats()["headset"]["tx_bytes"] - a) / 2.0
    hs.start("headset", "viewer", [console_script("softhand-record"), "-o", str(out / "viewer" / "bag"),
                                   "--topics", *VIEWER_TOPICS])
    hs.probe("headset", ["--sub", "/hand/right/skin_vertices"], timeout=60)
    time.sleep(1.0)
    b, t0 = lan.switch_stats()["headset"]["tx_bytes"], time.time()
    time.sleep(window)
    c, t1 = lan.switch_stats()["headset"]["tx_bytes"], time.time()
    assert hs.procs["headset"].stop("viewer") == 0
    data = read_bag(out / "viewer" / "bag")
    per_topic = {}
    for topic, rows in data.items():
        inside = [n for t, n, _ in rows if t0 <= t <= t1]
        per_topic[topic] = (len(inside) / (t1 - t0), float(np.mean([n for _, n, _ in rows])), sum(inside) / (t1 - t0))
    return {"link_bytes_per_s": (c - b) / (t1 - t0) - base, "baseline": base, "topics": per_topic}


@pytest.fixture(scope="module")
def lan_runs(tmp_path_factory):
    if os.environ.get("SOFTHAND_MULTIHOST") == "0":
        pytest.skip("across-hosts run switched off (SOFTHAND_MULTIHOST=0)")
    why = netns.why_not_available()
    if why:
        pytest.skip(why)
    out = tmp_path_factory.mktemp("hosts")
    domain = pick_domain_id()
    env = isolated_env(domain)
    # Inside the namespaces only: the LAN's default discovery (multicast on lan0 and loopback).
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    env["NUMBA_NUM_THREADS"] = "1"
    # as the README says for a LAN: UDP sends that never block (a dead link stalled sim_node 0.5 s)
    env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(REPO / "config" / "fastdds_lan.xml")
    host_counters = netns.host_interface_counters()
    capture = netns.HostCapture(domain)
    lan = netns.Lan(HOSTS)
    runs, result = [], {}
    try:
        lan.create()
        result["layout"] = {h: (lan.interfaces(h), [r["dst"] for r in lan.routes(h)]) for h in HOSTS}
        result["layout"]["sw"] = (lan.interfaces("sw"), [])
        hs = HostSet(lan, env, out / "logs")
        try:
            hs.start("server", "world", [console_script("softhand-world"), "--ros-args", *DIAG])
            hs.start("workstation", "sim", [console_script("softhand-sim"), "--ros-args", *DIAG])
            hs.start("headset", "tracking", [console_script("softhand-tracking"), "--ros-args", *DIAG])
            hs.probe("workstation", ["--pub", "/hand/right/bones", "/world/object_states",
                                     "/hand/right/intermediate_bones", "--sub", "/hand/right/bones",
                                     "/hand/object_states", "/hand/right/intermediate_bones"],
                     timeout=400)
            for name, bag_name, impairment in PHASES:
                runs.append(run_phase(hs, lan, out, name, bag_name, impairment))
                assert not runs[-1]["dead"], f"nodes died in {name}: {runs[-1]['dead']}\n{hs.tails()}"
                if name == "clean" and not summarize_run(runs[-1]["bag"], bag_name=bag_name, scores=False)["ball_lifted"]:
                    # the grasp slip seen on fresh clones in the single-host demo too (README, "What
                    # the tests prove"): tried once more, as the node-level demo tests are; counted
                    result["clean_retries"] = 1
                    runs[-1] = run_phase(hs, lan, out, "clean_again", bag_name, impairment)
                    runs[-1]["name"] = "clean"
            result["viewer"] = measure_viewer(hs, lan, out)
        finally:
            result["exit_codes"] = hs.stop_all()
            result["logs"] = hs.tails()
    finally:
        lan.remove()
        # control: packets this test sends on the machine's loopback to the domain's port must be seen
        ctl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        ctl.sendto(b"softhand-net-control", ("127.0.0.1", 7400 + 250 * domain + 249))
        ctl.close()
        time.sleep(0.5)
        result["captured"] = capture.stop()
        result["host_counters"] = (host_counters, netns.host_interface_counters())
        result["namespaces_left"] = [n for n in netns._namespaces() if n.startswith(lan.prefix)]
        release_domain_id(domain)
    result["runs"] = {r["name"]: r for r in runs}
    for r in runs:
        r["data"] = read_bag(r["bag"])
        # the checks read the ball's lift and all_finite of the summary: no lag and fidelity scores
        r["summary"] = summarize_run(r["bag"], bag_name=r["bag_name"], scores=False)
    return result


# ------------------------------------------------------------------------------------------ tests


def test_nothing_leaves_the_namespaces(lan_runs):
    """Every packet stayed on the LAN: the machine's interfaces saw only this test's control
    packets; each host has lo + lan0 and routes on lan0 only; the namespaces are gone afterwards."""
    for host in HOSTS:
        ifaces, routes = lan_runs["layout"][host]
        assert ifaces == ["lan0", "lo"], (host, ifaces)
        assert "default" not in routes and set(routes) <= {netns.SUBNET, netns.MULTICAST}, (host, routes)
    assert lan_runs["layout"]["sw"][0] == ["lo", "p-headset", "p-server", "p-workstation"]
    captured = lan_runs["captured"]
    control = [p for p in captured if b"softhand-net-control" in p[1] or p[1][30:34] == bytes([127, 0, 0, 1])]
    assert control, "the capture saw not even its control packet: it would not have seen a leak"
    leaks = [p for p in captured if p not in control]
    assert not leaks, f"{len(leaks)} LAN packets on the machine's interfaces: {leaks[:3]}"
    assert lan_runs["namespaces_left"] == []


def test_demo_across_hosts(lan_runs):
    """Clean network: the ball is lifted, every tracker frame and every sim step is recorded on the
    workstation, every node exits 0 at the end."""
    r = lan_runs["runs"]["clean"]
    s = r["summary"]
    assert s["ball_lifted"], f"ball rose {100 * s['ball_lift_m']:.1f} cm"
    assert s["all_finite"]
    assert r["record_code"] == 0 and r["play_code"] == 0
    assert all(c == 0 for c in lan_runs["exit_codes"].values()), lan_runs["exit_codes"]
    data = r["data"]
    # The recorder reads the tracker best effort (any tracker matches): a frame is lost only when the
    # recorder falls behind and its socket buffer overflows. Measured: 1171 of 1171 frames, and
    # 1160 of 1171 at load 11 on 2 cores with the recorder 1-2 s behind.
    assert len(data["/tracker/right/hand_joints"]) >= 0.99 * bag_frames(r["bag_name"])
    check_every_step_recorded(data)
    for topic, node in REMOTE:
        check_all_published_recorded(data, topic, node)


REMOTE = (("/hand/right/intermediate_bones", "tracking_node"), ("/world/object_states", "world_node"))


def check_all_published_recorded(data, topic, node, outage=None, count_key="published", stamp_key="published_stamp"):
    """No hole in the recording: every message `node` published on `topic` is in it. Each status
    of the node (its /diagnostics) gives how many it had published and the stamp of the last one,
    so the recorded messages stamped between two statuses' stamps must number exactly the
    difference. With an outage: before it, and from 1 s after it. The last status used is 1.5 s
    before the recorder's last message of the topic (its reliable copy trails by up to a second
    when packets are lost, and the phase ends by stopping it). Returns (published, recorded, the
    publisher's own stalls: stamp gaps > MAX_HOLE_S, when its process waited for a core and its
    schedule skipped ahead; reported, not holes of the recording)."""
    rows = [(t, int(v[count_key]), float(v[stamp_key])) for t, v in diag_rows(data, node)]
    stamps = np.sort([stamp_s(m) for _, _, m in data[topic]])
    last = max(t for t, _, _ in data[topic]) - 1.5
    segments = [[r for r in rows[1:] if r[0] < last]]
    if outage:
        segments = [[r for r in rows[1:] if r[0] < outage[0]], [r for r in rows if outage[1] + 1.0 < r[0] < last]]
    published = recorded = 0
    for seg in segments:
        assert len(seg) >= 2, (topic, node, "fewer than two statuses to count between", rows)
        (_, na, sa), (_, nb, sb) = seg[0], seg[-1]
        # (+0.1 ms: the statuses carry the stamps to 1 us; the messages are >= 4 ms apart)
        n = int(np.count_nonzero((stamps > sa + 1e-4) & (stamps <= sb + 1e-4)))
        assert n == nb - na, f"{topic}: {node} published {nb - na} stamped {sa:.3f}..{sb:.3f}, {n} recorded"
        published, recorded = published + nb - na, recorded + n
    return published, recorded, holes(list(stamps), outage)


def check_every_step_recorded(data, outage=None):
    """sim_node's step counter against the /hand/right/bones recorded (the workstation's own topic)."""
    return check_all_published_recorded(data, "/hand/right/bones", "sim_node", outage, "steps", "last_step_stamp")


@pytest.mark.parametrize("phase", ["delay", "loss", "outage"])
def test_bad_network_survived(lan_runs, phase):
    """No node died, every recorded value finite, /hand/right/bones never stopped, the tracked hand
    went on reaching the workstation, and no hole in the recording but the outage."""
    r = lan_runs["runs"][phase]
    assert not r["dead"] and r["record_code"] == 0 and r["play_code"] == 0
    assert r["summary"]["all_finite"]
    data = r["data"]
    for topic, node in REMOTE:  # remote, stamped by the publisher
        assert len(data[topic]) > 100, topic
        published, recorded, stalls = check_all_published_recorded(data, topic, node, r["outage"])
        print(f"\n{phase}: {topic}: {published} published, {recorded} recorded; "
              f"publisher stalls > {MAX_HOLE_S} s: {[round(d, 2) for _, d in stalls]}")
    check_every_step_recorded(data, r["outage"])  # /hand/right/bones: local, every step
    frames = len(data["/tracker/right/hand_joints"])  # best effort: lost packets are lost
    expected = bag_frames(r["bag_name"]) - (150 if phase == "outage" else 0)  # 1 s down: 100 frames
    assert frames >= 0.95 * expected, f"{frames} of {expected} tracker frames recorded"


def test_outage_hold_track_decouple_count(lan_runs):
    """Workstation link down 1 s: the hand holds its last target (at rest on it at the end of
    the outage), tracks again within 2 s, the world and sim decouple the stale copies and
    recouple, and /diagnostics counts the gaps."""
    r = lan_runs["runs"]["outage"]
    t_down, t_up = r["outage"]
    data = r["data"]
    # by the publishers' stamps: the recorder's receive times lag on a loaded machine
    inter = sorted((stamp_s(m), palm(m)) for _, _, m in data["/hand/right/intermediate_bones"])
    bones = sorted((stamp_s(m), palm(m)) for _, _, m in data["/hand/right/bones"])
    before = [p for t, p in inter if t < t_down]
    assert before, "no target before the outage"
    held = before[-1]
    # the link was down: the switch dropped what was sent to the workstation, and sim_node's
    # targets aged (the recorder's copies of them came after the link was back: STREAM_QOS resends)
    assert r["switch"]["workstation"]["down_drops"] > 100, r["switch"]
    sim = diag_rows(data, "sim_node")
    ages = [float(v["target_age_s"]) for t, v in sim if t_down + 0.5 < t < t_up + 0.1]
    assert ages and max(ages) > 0.4, f"sim_node's targets never aged in the outage: {ages}"
    end = [p for t, p in bones if t_up - 0.5 <= t <= t_up]
    assert len(end) >= 2, "sim_node published nothing in the last 0.5 s of the outage"
    assert np.linalg.norm(end[-1] - end[0]) < 0.005, "the hand was still moving at the end of the outage"
    assert np.linalg.norm(end[-1] - held) < 0.03, "the hand did not hold the last target"
    # sim_node's own view (its /diagnostics, stamped by its clock): targets fresh again within 2 s
    fresh = [t for t, v in sim if t > t_up and 0.0 <= float(v["target_age_s"]) < 0.25]
    assert fresh and fresh[0] - t_up < 2.0, f"sim_node got no new target within 2 s of the link coming back: {fresh[:3]}"
    # tracks again: within 2 s the simulated palm is on the (live) intermediate palm again
    close = [t for t, p in bones if t_up < t < t_up + 2.0
             and np.linalg.norm(p - inter[np.searchsorted([x for x, _ in inter], t) - 1][1]) < 0.02]
    assert close, "the simulated hand did not catch up with its targets within 2 s"

    world = diag_rows(data, "world_node")
    # a copy is stale 0.5 s after its last update (copy_timeout); the status saying so comes at the
    # next diagnostics tick, which a loaded core can delay past the link coming back
    stale_w = [v["stale_copies"] for t, v in world if t_down + 0.5 < t < t_up + 0.5]
    stale_s = [v["stale_objects"] for t, v in sim if t_down + 0.5 < t < t_up + 0.5]
    assert any(s for s in stale_w), f"world_node never decoupled: {stale_w}"
    assert any(s not in ("", "-") for s in stale_s), f"sim_node never decoupled: {stale_s}"
    assert world[-1][1]["stale_copies"] == "" and sim[-1][1]["stale_objects"] == "-", "not recoupled"
    tracking = diag_rows(data, "tracking_node")

    def grew(rows, key):  # the counter (cumulative over the node's life) rose across the outage
        pre = [int(v[key]) for t, v in rows if t < t_down]
        return pre and int(rows[-1][1][key]) > pre[-1]
    assert grew(world, "copy_gaps") and grew(sim, "copy_gaps"), "decoupling not counted"
    assert grew(sim, "target_gaps"), "the target gap not counted"
    assert grew(tracking, "sim_copy_drops") and tracking[-1][1]["sim_copy"] == "True", "sim copy drop not counted"


def test_latency_and_bandwidth_table(lan_runs):
    """Prints the measured table (pytest -s); checks that the delay shows in the latency and that
    the link counters agree with the per-topic figures."""
    lines = ["", "phase   UDP RTT headset<->ws p10/p50 [ms]  sim: target delay p50 [ms], step p50 [ms], rate [Hz]"
                 "  => tracker->bones [ms]   recorder's view: e2e p50, one-way p50 [ms]"]
    lat = {}
    for name, r in lan_runs["runs"].items():
        e2e, one_way = latency(r["data"])
        rows = [v for _, v in diag_rows(r["data"], "sim_node")][1:]
        sim_delay = np.nanmedian([float(v["target_delay_ms_p50"]) for v in rows])
        step = np.nanmedian([float(v["step_ms_p50"]) for v in rows])
        rate = np.nanmedian([float(v["sim_rate_hz"]) for v in rows])
        # a frame waits <= 4 ms for the 250 Hz tracking step, then target delay, then on average half
        # a sim period for the next step, which publishes /hand/right/bones step_ms later
        model = 2.0 + sim_delay + 500.0 / rate + step
        lat[name] = (np.percentile(r["rtt"], 10), model)
        lines.append(f"{name:7s} {np.percentile(r['rtt'], 10):14.1f} / {np.percentile(r['rtt'], 50):6.1f} "
                     f"{sim_delay:22.1f} {step:10.1f} {rate:10.1f} {model:16.1f} "
                     f"{np.percentile(e2e, 50):22.1f} {np.percentile(one_way, 50):9.1f}")
    lines.append(f"clean phase tried again after a grasp slip: {lan_runs.get('clean_retries', 0)} time(s)")
    clean = lan_runs["runs"]["clean"]
    table = topic_bytes(clean["data"], clean["span"])
    lines.append("")
    lines.append("clean run, per topic: rate [Hz], size [B], recorded [kB/s]; on the links [kB/s]")
    link = {h: {"up": 0.0, "down": 0.0} for h in HOSTS}
    for topic, (rate, size, bps) in sorted(table.items()):
        route = ROUTES.get(topic)
        where = ""
        if route:
            src, dst = route
            fan = sum(dst.values())
            link[src]["up"] += bps * fan
            for h, n in dst.items():
                link[h]["down"] += bps * n
            where = f"{src} -> " + ", ".join(f"{h} x{n}" for h, n in dst.items()) + f": {fan * bps / 1e3:.1f}"
        else:
            where = "workstation only"
        lines.append(f"  {topic:28s} {rate:7.1f} {size:9.0f} {bps / 1e3:9.1f}   {where}")
    lines.append("links, clean run [kB/s]: payload estimate (topics above) vs measured at the switch (all frames)")
    for h in HOSTS:
        sw = clean["switch"][h]
        lines.append(f"  {h:12s} up {link[h]['up'] / 1e3:7.1f} est {sw['rx_bytes'] / clean['span'] / 1e3:7.1f} "
                     f"measured ({sw['rx_frames'] / clean['span']:.0f} frames/s); down {link[h]['down'] / 1e3:7.1f} "
                     f"est {sw['tx_bytes'] / clean['span'] / 1e3:7.1f} measured")
    for name, r in lan_runs["runs"].items():
        lines.append(f"  switch, {name}: " + json.dumps(r["switch"]))
    v = lan_runs["viewer"]
    lines.append(f"remote viewer on the headset (sim defaults): its link carries {v['link_bytes_per_s'] / 1e6:.2f} MB/s "
                 f"more (baseline {v['baseline'] / 1e3:.1f} kB/s)")
    for topic, (rate, size, bps) in sorted(v["topics"].items()):
        lines.append(f"  {topic:28s} {rate:7.1f} Hz {size / 1e3:9.1f} kB {bps / 1e6:7.2f} MB/s "
                     f"(at one hand's 150 Hz / marker 10 Hz: {size * (150 if 'vertices' in topic else 10) / 1e6:.2f} MB/s)")
    print("\n".join(lines))
    assert lat["delay"][0] > lat["clean"][0] + 25.0, lat   # 2 x (20 - 5) ms more on the round trip
    assert all(np.isfinite(v).all() for v in lat.values()), lat
    skin_rate, skin_size, skin_bps = v["topics"]["/hand/right/skin_vertices"]
    assert skin_size > 100e3 and skin_rate > 5.0, v["topics"]
    assert v["link_bytes_per_s"] >= 0.8 * sum(x[2] for x in v["topics"].values()), v
    for h in HOSTS:  # the topics explain the traffic: DDS framing and acks add, never remove
        measured = clean["switch"][h]["rx_bytes"] / clean["span"]
        assert measured >= 0.8 * link[h]["up"], (h, measured, link[h]["up"])

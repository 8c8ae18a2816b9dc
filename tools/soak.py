"""Soak test of the whole node set (issue #10 item 7): a tracker bag looped through world, sim,
tracking, record and play nodes for N minutes, sampling each process's resident memory and rates.

    .venv/bin/python tools/soak.py                      # 30 minutes, bag grasp_lift
    .venv/bin/python tools/soak.py --minutes 5 --bag fast_dropout --period 10

Every `period` seconds (default 10) it samples, per process, VmRSS from /proc/<pid>/status (no
psutil), and the rates: sim_node sim_rate_hz, tracking_node rate_hz, world_node engine_rate_hz
(their /diagnostics), tracker frames reaching tracking_node (frames_accepted + frames_rejected per
second) and messages written by record_node (its progress log). After the warm-up (default: the
larger of 60 s and 20 % of the run) it reports, per process, whether RSS stayed flat within
--rss-tolerance (5 %: (max - min) / first sample after warm-up) with the fitted slope in MB/h,
and per rate whether it decayed (median of the last third < 95 % of the first third), next to the
system load average early and late (a rate that drops while the load rises is contention). Samples and
the report go to OUT/soak.json; the report is printed, with the solver guard's rejected steps and
a warning when another run's nodes showed up on the same ROS domain (random ids can collide). Exit code 0 when every node stayed up, RSS
was flat and no rate decayed, 1 otherwise.

Processes run with loopback-only discovery on a private ROS_DOMAIN_ID (softhand_sim.ros.env).
The recording (default: the light topics, no skin marker / vertices) is deleted at the end unless
--keep-bag.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import threading
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from softhand_sim.commands.demo import ProcessSet, console_script, ready_topics, resolve_bag
from softhand_sim.paths import REPO_ROOT
from softhand_sim.ros.env import apply_isolated_env, isolated_env
from softhand_sim.ros.probe import wait_for_topics

NODES = ("world", "sim", "tracking")  # started first; then record and play
# (process, diagnostics status name, diagnostics key) of each rate taken from /diagnostics
DIAG_RATES = {"sim_hz": ("sim_node", "sim_rate_hz"), "tracking_hz": ("tracking_node", "rate_hz"),
              "world_hz": ("world_node", "engine_rate_hz")}
RECORD_TOPICS = ("/tracker/right/hand_joints", "/hand/right/intermediate_bones", "/hand/right/bones",
                 "/hand/object_states", "/world/object_states", "/hand/contacts", "/diagnostics")
OUR_NODES = ("world_node", "sim_node", "tracking_node", "record_node", "play_node")
DECAY = 0.95  # a rate whose late median is below this share of its early median decayed


def rss_mb(pid: int) -> float:
    """Resident set size [MB] of a process from /proc/<pid>/status (NaN if it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return float("nan")


class DiagnosticsWatch:
    """Latest /diagnostics values per status name, from an rclpy node spinning in a thread."""

    def __init__(self, domain_id: int):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor

        from softhand_sim.ros.common import PUB_QOS
        from softhand_sim.ros.msgs import status_node

        self._rclpy = rclpy
        self._status_node = status_node
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("softhand_soak_watch", context=self.context)
        self.latest = {}
        self._lock = threading.Lock()
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, PUB_QOS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on_diag(self, msg):
        with self._lock:
            for st in msg.status:
                self.latest[self._status_node(st.name)] = {kv.key: kv.value for kv in st.values}

    def _spin(self):
        while not self._stop.is_set() and self.context.ok():
            self.executor.spin_once(timeout_sec=0.1)

    def duplicate_nodes(self, names):
        """How many extra nodes carry one of `names` in the graph: > 0 means another run shares this
        ROS domain (its diagnostics and messages then mix with ours and the figures are void)."""
        graph = [n for n, _ns in self.node.get_node_names_and_namespaces()]
        return sum(max(0, graph.count(n) - 1) for n in names)

    def get(self, name, key, default=float("nan")):
        with self._lock:
            try:
                return float(self.latest[name][key])
            except (KeyError, ValueError):
                return default

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        self._rclpy.try_shutdown(context=self.context)


def load_average() -> float:
    """1-minute system load average (other processes competing for the cores lower every rate)."""
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def record_count(log_path: Path) -> float:
    """Messages written so far by record_node, from its last progress line (NaN before the first)."""
    try:
        text = log_path.read_text(errors="replace")
    except OSError:
        return float("nan")
    found = re.findall(r"(\d+) messages, [\d.]+ MB", text)
    return float(found[-1]) if found else float("nan")


def analyse(samples, warmup_s, rss_tolerance):
    """Report dict from the samples: RSS flatness per process, rate decay per rate."""
    t = np.array([s["t"] for s in samples])
    after = t >= warmup_s
    report = {"samples": int(len(samples)), "samples_after_warmup": int(after.sum()), "rss": {}, "rates": {},
              "foreign_node_samples": int(sum(s.get("foreign_nodes", 0) > 0 for s in samples)),
              "sim_rejected_steps": samples[-1].get("sim_rejected_steps", float("nan"))}
    if after.sum() < 3:
        report["error"] = "fewer than 3 samples after warm-up: run longer or shorten --warmup / --period"
        return report
    for name in samples[0]["rss_mb"]:
        r = np.array([s["rss_mb"][name] for s in samples])[after]
        ta = t[after]
        ok = np.isfinite(r)
        first, last, lo, hi = r[ok][0], r[ok][-1], r[ok].min(), r[ok].max()
        slope = float(np.polyfit(ta[ok] / 3600.0, r[ok], 1)[0]) if ok.sum() >= 2 else float("nan")
        report["rss"][name] = {"first_mb": round(float(first), 1), "last_mb": round(float(last), 1),
                               "min_mb": round(float(lo), 1), "max_mb": round(float(hi), 1),
                               "spread_pct": round(100.0 * (hi - lo) / first, 2),
                               "slope_mb_per_h": round(slope, 2),
                               "flat": bool((hi - lo) <= rss_tolerance * first and ok.all())}
    n = int(after.sum())
    third = max(1, n // 3)
    load = np.array([s.get("load1", np.nan) for s in samples])[after]
    # A rate that drops while the machine's load rises is contention from other processes, not decay
    # of the node itself: the report gives both so that a reader can tell them apart.
    report["load1"] = {"early_median": round(float(np.nanmedian(load[:third])), 2),
                       "late_median": round(float(np.nanmedian(load[-third:])), 2),
                       "cpu_count": os.cpu_count()}
    for key in samples[0]["rates"]:
        r = np.array([s["rates"][key] for s in samples])[after]
        early, late = np.nanmedian(r[:third]), np.nanmedian(r[-third:])
        report["rates"][key] = {"early_median": round(float(early), 2), "late_median": round(float(late), 2),
                                "min": round(float(np.nanmin(r)), 2), "max": round(float(np.nanmax(r)), 2),
                                "decayed": bool(not np.isfinite(late) or late < DECAY * early)}
    return report


def run(args):
    bag = resolve_bag(args.bag)
    out = Path(args.out) if args.out else REPO_ROOT / "runs" / f"soak-{datetime.now():%Y%m%d-%H%M%S}"
    out.mkdir(parents=True, exist_ok=True)
    duration = 60.0 * args.minutes
    warmup = args.warmup if args.warmup is not None else max(60.0, 0.2 * duration)
    env = isolated_env()
    apply_isolated_env(env["ROS_DOMAIN_ID"])
    procs = ProcessSet(env, out / "logs")
    print(f"soak: {args.minutes:g} min of {bag.name} (looped), sample every {args.period:g} s, warm-up "
          f"{warmup:.0f} s, out {out} (ROS_DOMAIN_ID={env['ROS_DOMAIN_ID']})", flush=True)
    samples, died, watch = [], [], None
    try:
        for name in NODES:
            procs.start(name, [console_script(f"softhand-{name}")])
        missing = wait_for_topics(ready_topics(("right",)), 600.0, procs)
        if missing:
            raise SystemExit(f"error: no publisher on {missing}; see {out / 'logs'}")
        procs.start("record", [console_script("softhand-record"), "-o", str(out / "bag"), "--topics", *RECORD_TOPICS,
                               "--ros-args", "-p", f"progress_period:={min(args.period, 5.0)}"])
        time.sleep(2.0)
        procs.start("play", [console_script("softhand-play"), str(bag), "--loop", "--wait-subscribers", "1"])
        watch = DiagnosticsWatch(int(env["ROS_DOMAIN_ID"]))
        t0 = time.monotonic()
        prev = None
        while True:
            time.sleep(max(0.0, t0 + (len(samples) + 1) * args.period - time.monotonic()))
            now = time.monotonic()
            died = [n for n in procs.procs if not procs.alive(n)]
            frames = (watch.get("tracking_node", "frames_accepted", np.nan)
                      + watch.get("tracking_node", "frames_rejected", np.nan))
            written = record_count(out / "logs" / "record.log")
            rates = {key: watch.get(node, k) for key, (node, k) in DIAG_RATES.items()}
            rates["tracker_frames_hz"] = (frames - prev[1]) / (now - prev[0]) if prev else float("nan")
            rates["recorded_msgs_hz"] = (written - prev[2]) / (now - prev[0]) if prev else float("nan")
            prev = (now, frames, written)
            sample = {"t": round(now - t0, 2), "load1": load_average(),
                      "sim_rejected_steps": watch.get("sim_node", "rejected_steps", np.nan),
                      "foreign_nodes": watch.duplicate_nodes(OUR_NODES),
                      "rss_mb": {n: round(rss_mb(procs.procs[n][0].pid), 2) for n in procs.procs},
                      "rates": {k: round(v, 2) for k, v in rates.items()}}
            samples.append(sample)
            print(f"  t={sample['t']:7.1f} s  RSS [MB] " + " ".join(f"{n} {v:.0f}" for n, v in sample["rss_mb"].items())
                  + "  rates [Hz] " + " ".join(f"{k} {v:.1f}" for k, v in sample["rates"].items())
                  + f"  load {sample['load1']:.1f}  guard rejections {sample['sim_rejected_steps']:.0f}"
                  + (f"  FOREIGN NODES {sample['foreign_nodes']}" if sample["foreign_nodes"] else ""), flush=True)
            if died:
                print(f"error: process(es) exited: {died}", flush=True)
                for n in died:
                    print(f"--- {n} ---\n{procs.tail(n, 30)}", flush=True)
                break
            if now - t0 >= duration:
                break
    finally:
        if watch is not None:
            watch.close()
        codes = procs.stop_all()
    report = analyse(samples, warmup, args.rss_tolerance) if samples else {"error": "no samples"}
    report.update(minutes=args.minutes, bag=bag.name, period_s=args.period, warmup_s=warmup,
                  exit_codes=codes, died=died, rss_tolerance=args.rss_tolerance)
    report["ok"] = bool(not died and "error" not in report and not report.get("foreign_node_samples")
                        and all(v["flat"] for v in report["rss"].values())
                        and not any(v["decayed"] for v in report["rates"].values()))
    (out / "soak.json").write_text(json.dumps({"report": report, "samples": samples}, indent=2))
    if not args.keep_bag:
        shutil.rmtree(out / "bag", ignore_errors=True)
    print(format_report(report), flush=True)
    return 0 if report["ok"] else 1


def format_report(r):
    lines = [f"soak report ({r['minutes']:g} min, {r.get('samples_after_warmup', 0)} samples after "
             f"{r['warmup_s']:.0f} s warm-up): {'OK' if r['ok'] else 'PROBLEM'}"]
    if "error" in r:
        lines.append(f"  {r['error']}")
    for name, v in r.get("rss", {}).items():
        lines.append(f"  RSS {name:9s} {v['first_mb']:7.1f} -> {v['last_mb']:7.1f} MB (min {v['min_mb']:.1f}, max "
                     f"{v['max_mb']:.1f}, spread {v['spread_pct']:.2f} %, slope {v['slope_mb_per_h']:+.1f} MB/h): "
                     f"{'flat' if v['flat'] else 'NOT flat'}")
    for key, v in r.get("rates", {}).items():
        lines.append(f"  rate {key:18s} early {v['early_median']:7.1f}  late {v['late_median']:7.1f} Hz "
                     f"(min {v['min']:.1f}, max {v['max']:.1f}): {'DECAYED' if v['decayed'] else 'steady'}")
    if "load1" in r:
        lines.append(f"  system load (1 min) early {r['load1']['early_median']:.1f}, late {r['load1']['late_median']:.1f} "
                     f"on {r['load1']['cpu_count']} cores (rates drop under contention)")
    lines.append(f"  sim_node guard rejections (diverged steps): {r.get('sim_rejected_steps', float('nan')):.0f}")
    if r.get("foreign_node_samples"):
        lines.append(f"  WARNING: {r['foreign_node_samples']} samples saw another run's nodes on this ROS domain: "
                     "rates and counts of those samples are mixed with it")
    lines.append(f"  exit codes {r['exit_codes']}" + (f"; died: {r['died']}" if r["died"] else ""))
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(prog="soak.py", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--minutes", type=float, default=30.0, help="run length after start-up (default 30)")
    p.add_argument("--bag", default="grasp_lift", help="tracker bag directory or sample name (default grasp_lift)")
    p.add_argument("--period", type=float, default=10.0, help="seconds between samples (default 10)")
    p.add_argument("--warmup", type=float, default=None, help="seconds left out of the verdicts "
                   "(default max(60, 20%% of the run))")
    p.add_argument("--rss-tolerance", type=float, default=0.05, help="allowed RSS spread after warm-up (0.05)")
    p.add_argument("--out", default=None, help="output directory (default runs/soak-<stamp>)")
    p.add_argument("--keep-bag", action="store_true", help="keep the recording")
    args = p.parse_args(argv)
    for name in ("minutes", "period"):
        if getattr(args, name) <= 0:
            p.error(f"--{name} must be > 0, got {getattr(args, name)}")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())

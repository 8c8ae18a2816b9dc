"""Hosts of our own for tests across machines: Linux network namespaces on a virtual switch.

    with Lan(["headset", "workstation", "server"]) as lan:     # root and iproute2 needed
        argv = lan.exec_argv("server", ["softhand-world"])     # ip netns exec <ns> softhand-world
        lan.netem("delay 20ms 5ms")                           # every host's uplink
        lan.link_down("workstation"); ...; lan.link_up("workstation")
        lan.counters()                                        # bytes/packets per switch port

Layout (nothing is ever created in the machine's own namespace, so no packet can reach its
interfaces):
    <prefix>sw           the switch: one port `p-<host>` per host, the switch end of the host's veth
                         pair, forwarded by tests/support/userswitch.py (a learning switch in user
                         space that also delays, jitters and drops: this kernel has no tc netem)
    <prefix><host>       one namespace per host: `lo` up, `lan0` = ADDRESS_FMT.format(i) in
                         SUBNET, the route SUBNET and a multicast route 224.0.0.0/4 on lan0
                         (DDS discovery multicasts to 239.255.0.1); no default route
The veth pairs are created inside the switch namespace with the peer directly in the host's
(`ip -n SW link add ... peer ... netns HOST`). The prefix holds this process's pid, so a
later run removes the namespaces of a run that died (`remove_stale`) without touching a live one.

Impairments act on each host's uplink (frames entering the switch from that host): a packet
between two hosts crosses exactly one, so `impair(delay_ms=20, jitter_ms=5)` is 20 +- 5 ms one
way between hosts and `impair(loss_percent=2)` is 2 % per host-to-host packet. A link down is the
switch port going down (a pulled cable): the host's lan0 loses carrier, its addresses and routes
stay.
"""
from __future__ import annotations

import ctypes
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

PREFIX_ROOT = "shnet-"        # every namespace of these tests starts with this
SUBNET = "10.231.0.0/24"
ADDRESS_FMT = "10.231.0.{}"   # host i gets .(i + 1)
MULTICAST = "224.0.0.0/4"


def why_not_available() -> str:
    """'' when this process can build namespaces, else the reason (for pytest.skip)."""
    if os.geteuid() != 0:
        return "network namespaces need root (ip netns add)"
    if shutil.which("ip") is None:
        return "iproute2 (`ip`) is not installed"
    probe = f"{PREFIX_ROOT}probe-{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"`ip netns add` failed: {r.stderr.strip()}"
    try:
        r = subprocess.run(["ip", "-n", probe, "link", "add", "probe0", "type", "veth", "peer", "name", "probe1"],
                           capture_output=True, text=True)
        if r.returncode != 0:
            return f"cannot create a veth pair: {r.stderr.strip()}"
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return ""


def _ip(*args, check=True):
    r = subprocess.run(["ip", *args], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise RuntimeError(f"ip {' '.join(args)}: {r.stderr.strip()}")
    return r.stdout


def _namespaces():
    return [line.split()[0] for line in _ip("netns", "list").splitlines() if line.strip()]


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_namespace(ns: str) -> None:
    """Kill what still runs in `ns` (by pid: only processes inside our own namespace) and delete it."""
    pids = [int(p) for p in _ip("netns", "pids", ns, check=False).split()]
    for pid in pids:
        try:
            os.kill(pid, 9)
        except ProcessLookupError:
            pass
    _ip("netns", "del", ns, check=False)


def remove_stale() -> list:
    """Remove the namespaces of earlier runs whose process is gone; returns their names."""
    gone = []
    for ns in _namespaces():
        if not ns.startswith(PREFIX_ROOT):
            continue
        try:
            pid = int(ns[len(PREFIX_ROOT):].split("-")[0])
        except ValueError:
            pid = -1
        if pid != os.getpid() and not _pid_alive(pid):
            remove_namespace(ns)
            gone.append(ns)
    return gone


class Lan:
    """Hosts (network namespaces) on one switch; see the module docstring for the layout."""

    def __init__(self, hosts, prefix: str | None = None):
        self.hosts = list(hosts)
        self.prefix = prefix or f"{PREFIX_ROOT}{os.getpid()}-"
        self.switch = f"{self.prefix}sw"
        self.address = {h: ADDRESS_FMT.format(i + 1) for i, h in enumerate(self.hosts)}
        self.made = []
        self.switch_proc = None

    def ns(self, host: str) -> str:
        return f"{self.prefix}{host}"

    def port(self, host: str) -> str:
        return f"p-{host}"[:15]

    # ------------------------------------------------------------------------------ build / remove
    def create(self) -> "Lan":
        remove_stale()
        try:
            self._create()
        except BaseException:
            self.remove()
            raise
        return self

    def _add_ns(self, ns):
        _ip("netns", "add", ns)
        self.made.append(ns)
        _ip("-n", ns, "link", "set", "lo", "up")

    def _create(self):
        sw = self.switch
        self._add_ns(sw)
        prefix_len = SUBNET.split("/")[1]
        for host in self.hosts:
            ns, port = self.ns(host), self.port(host)
            self._add_ns(ns)
            _ip("-n", sw, "link", "add", port, "type", "veth", "peer", "name", "lan0", "netns", ns)
            _ip("-n", sw, "link", "set", port, "up")
            _ip("-n", ns, "addr", "add", f"{self.address[host]}/{prefix_len}", "dev", "lan0")
            _ip("-n", ns, "link", "set", "lan0", "up")
            _ip("-n", ns, "route", "add", MULTICAST, "dev", "lan0")
        script = Path(__file__).with_name("userswitch.py")
        self.switch_proc = subprocess.Popen(
            ["ip", "netns", "exec", sw, sys.executable, str(script), *(self.port(h) for h in self.hosts)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1,
            # the switch is the network, not a workload: not niced with the test (else a loaded
            # machine starves it and its queueing shows up as network delay and loss)
            preexec_fn=lambda: os.setpriority(os.PRIO_PROCESS, 0, 0))

    def _switch(self, command: str) -> str:
        self.switch_proc.stdin.write(command + "\n")
        self.switch_proc.stdin.flush()
        return self.switch_proc.stdout.readline()

    def remove(self) -> None:
        if self.switch_proc is not None:
            try:
                self.switch_proc.stdin.close()
                self.switch_proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self.switch_proc.kill()
                self.switch_proc.wait()
            self.switch_proc = None
        for ns in reversed(self.made):
            remove_namespace(ns)
        self.made = []

    def __enter__(self):
        return self.create()

    def __exit__(self, *exc):
        self.remove()
        return False

    # ------------------------------------------------------------------------------------- use
    def exec_argv(self, host: str, argv) -> list:
        """argv run inside `host`'s namespace (ip netns exec execs it: the pid is the command's)."""
        return ["ip", "netns", "exec", self.ns(host), *argv]

    def run(self, host: str, argv, **kw):
        return subprocess.run(self.exec_argv(host, argv), capture_output=True, text=True, **kw)

    def impair(self, delay_ms=0.0, jitter_ms=0.0, loss_percent=0.0, hosts=None) -> None:
        """Delay +- jitter and loss on each host's uplink (all zero: a clean network)."""
        for host in hosts or self.hosts:
            reply = self._switch(f"set {self.port(host)} {delay_ms} {jitter_ms} {loss_percent}")
            if reply.strip() != "ok":
                raise RuntimeError(f"switch did not take the impairment for {host}: {reply!r}")

    def switch_stats(self) -> dict:
        """{host: frames/bytes received from it (rx) and sent to it (tx), lost, down_drops} at the switch."""
        raw = json.loads(self._switch("stats"))
        return {h: raw[self.port(h)] for h in self.hosts}

    def link_down(self, host: str) -> None:
        _ip("-n", self.switch, "link", "set", self.port(host), "down")

    def link_up(self, host: str) -> None:
        _ip("-n", self.switch, "link", "set", self.port(host), "up")

    def counters(self) -> dict:
        """{host: {rx_bytes, tx_bytes, rx_packets, tx_packets, ...}} of each host's lan0 (host's view)."""
        out = {}
        for host in self.hosts:
            stats = json.loads(_ip("-n", self.ns(host), "-j", "-s", "link", "show", "lan0"))[0]["stats64"]
            out[host] = {f"rx_{k}": v for k, v in stats["rx"].items()} | {f"tx_{k}": v for k, v in stats["tx"].items()}
        return out

    def interfaces(self, host_or_switch: str) -> list:
        ns = self.switch if host_or_switch == "sw" else self.ns(host_or_switch)
        return sorted(link["ifname"] for link in json.loads(_ip("-n", ns, "-j", "link", "show")))

    def routes(self, host: str) -> list:
        return json.loads(_ip("-n", self.ns(host), "-j", "route", "show"))


# ---------------------------------------------------------------------------------- host capture


def host_interface_counters() -> dict:
    """{ifname: (rx_packets, tx_packets)} of the machine's own namespace (this process's)."""
    out = {}
    for name in sorted(os.listdir("/sys/class/net")):
        try:
            rx = int(open(f"/sys/class/net/{name}/statistics/rx_packets").read())
            tx = int(open(f"/sys/class/net/{name}/statistics/tx_packets").read())
        except OSError:
            continue
        out[name] = (rx, tx)
    return out


class HostCapture:
    """Counts packets on every interface of this process's (the machine's) namespace that belong
    to the LAN: IPv4 from or to 10.231.0.0/16, or UDP to a port of the DDS domain's range
    (7400 + 250 * domain ... + 249). A classic BPF filter in the kernel passes only those, so
    the machine's own traffic is not copied into Python. Expected: zero.
    """

    def __init__(self, domain_id: int):
        lo = 7400 + 250 * int(domain_id)
        hi = lo + 249
        net = 0x0AE70000  # 10.231.0.0/16
        ins = [  # (code, jt, jf, k); jumps count the instructions skipped
            (0x28, 0, 0, 12),          # 0 ldh [12]          ethertype
            (0x15, 0, 13, 0x0800),     # 1 jeq IPv4, else drop
            (0x20, 0, 0, 26),          # 2 ld [26]           source address
            (0x54, 0, 0, 0xFFFF0000),  # 3 and /16
            (0x15, 9, 0, net),         # 4 jeq net -> accept
            (0x20, 0, 0, 30),          # 5 ld [30]           destination address
            (0x54, 0, 0, 0xFFFF0000),  # 6
            (0x15, 6, 0, net),         # 7 jeq net -> accept
            (0x30, 0, 0, 23),          # 8 ldb [23]          protocol
            (0x15, 0, 5, 17),          # 9 jeq UDP, else drop
            (0xB1, 0, 0, 14),          # 10 ldxb 4*([14]&0xf) IP header length
            (0x48, 0, 0, 16),          # 11 ldh [x+16]       UDP destination port
            (0x35, 0, 2, lo),          # 12 jge lo, else drop
            (0x25, 1, 0, hi),          # 13 jgt hi -> drop, else accept
            (0x06, 0, 0, 0x40000),     # 14 accept
            (0x06, 0, 0, 0),           # 15 drop
        ]
        self._prog = ctypes.create_string_buffer(b"".join(struct.pack("HBBI", *i) for i in ins))
        fprog = struct.pack("HL", len(ins), ctypes.addressof(self._prog))
        # ETH_P_ALL on every interface of this namespace. Packets queued before the filter was
        # attached are read and dropped (started before the LAN exists, none can be ours).
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(0x0003))
        self.sock.setsockopt(socket.SOL_SOCKET, 26, fprog)  # SO_ATTACH_FILTER
        self.sock.setblocking(False)
        try:
            while True:
                self.sock.recv(65535)
        except BlockingIOError:
            pass
        self.sock.settimeout(0.2)
        self.packets = []  # (ifname, first 64 bytes) of each packet that matched
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except socket.timeout:
                continue
            except OSError:
                return
            if len(self.packets) < 1000:
                self.packets.append((addr[0], data[:64]))

    def stop(self) -> list:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()
        return self.packets


def wait_for(predicate, timeout: float, what: str, poll: float = 0.1) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)

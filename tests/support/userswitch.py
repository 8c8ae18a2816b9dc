"""A learning Ethernet switch in user space with per-port impairments: delay, jitter, loss.

Run inside the switch namespace of tests/support/netns.py (`Lan`), one AF_PACKET socket per port:

    python userswitch.py p-headset p-workstation p-server      # commands on stdin, one per line:
      set PORT DELAY_MS JITTER_MS LOSS_PERCENT                 # impair frames entering from PORT
      stats                                                     # one JSON line on stdout
      quit

Why not a kernel bridge with `tc qdisc ... netem`: kernels built without CONFIG_NET_SCH_NETEM
(this machine's, a Firecracker VM) have no netem and no tc classifier to drop with either. The
impairment follows netem's semantics on the host's uplink: each frame a host sends gets
DELAY +- JITTER (uniform, as netem without a distribution table) and is dropped with
probability LOSS. Frames from one port leave in the order they came (a frame waits for the one
before it, as netem with a pfifo child does): a cable does not reorder, and a best-effort reader
drops a sample that arrives after a newer one (tracker frames sent back to back by a stalled
player would otherwise be lost to reordering, not to the network). A frame to a known unicast MAC goes to its
port, anything else (broadcast, DDS discovery multicast, unknown) to every other port.

Frames are forwarded as read. Two fixes make them valid again on the other veth: UDP checksums
left for offload (CHECKSUM_PARTIAL on the sender's veth, never filled in) are set to 0 ("no
checksum", allowed by IPv4) on unfragmented datagrams; fragments carry a full checksum already.
A port that is down (link_down: `ip link set p-x down`) drops what is sent to it.
"""
import heapq
import json
import random
import select
import socket
import sys
import time

ETH_P_ALL = 0x0003
PACKET_OUTGOING = 4


def fix_udp_checksum(frame: bytearray) -> None:
    if len(frame) < 42 or frame[12:14] != b"\x08\x00" or frame[23] != 17:
        return
    if (int.from_bytes(frame[20:22], "big") & 0x3FFF) != 0:  # a fragment: MF set or offset > 0
        return
    ihl = (frame[14] & 0x0F) * 4
    frame[14 + ihl + 6:14 + ihl + 8] = b"\x00\x00"


class Port:
    def __init__(self, name):
        self.name = name
        self.sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        self.sock.bind((name, ETH_P_ALL))
        # room for a burst (a 142 kB skin message is ~100 frames) while this process waits for a core
        self.sock.setsockopt(socket.SOL_SOCKET, 33, 8 << 20)  # SO_RCVBUFFORCE
        self.sock.setsockopt(socket.SOL_SOCKET, 32, 8 << 20)  # SO_SNDBUFFORCE
        self.sock.setblocking(False)
        self.delay = self.jitter = self.loss = 0.0
        self.rx_frames = self.rx_bytes = self.tx_frames = self.tx_bytes = 0
        self.lost = self.down_drops = 0
        self.last_release = 0.0


def main(names):
    ports = [Port(n) for n in names]
    by_fd = {p.sock.fileno(): p for p in ports}
    macs = {}   # MAC -> Port
    queue = []  # (release time, seq, frame, ingress Port)
    seq = 0
    rng = random.Random(1)
    stdin = sys.stdin.fileno()
    running = True

    def forward(frame, src):
        dst = macs.get(bytes(frame[0:6])) if not frame[0] & 1 else None
        for p in ([dst] if dst is not None else ports):
            if p is src:
                continue
            try:
                p.sock.send(frame)
                p.tx_frames += 1
                p.tx_bytes += len(frame)
            except OSError:  # port down (ENETDOWN, ENXIO): the frame is gone, like on a pulled cable
                p.down_drops += 1

    while running:
        now = time.monotonic()
        while queue and queue[0][0] <= now:
            _, _, frame, src = heapq.heappop(queue)
            forward(frame, src)
        timeout = max(0.0, queue[0][0] - now) if queue else 0.5
        ready, _, _ = select.select([stdin, *by_fd], [], [], timeout)
        for fd in ready:
            if fd == stdin:
                line = sys.stdin.readline()
                words = line.split()
                if not line or words[:1] == ["quit"]:
                    running = False
                elif words[:1] == ["set"]:
                    p = next(p for p in ports if p.name == words[1])
                    p.delay, p.jitter, p.loss = float(words[2]) / 1e3, float(words[3]) / 1e3, float(words[4]) / 100
                    print("ok", flush=True)
                elif words[:1] == ["stats"]:
                    print(json.dumps({p.name: {k: getattr(p, k) for k in (
                        "rx_frames", "rx_bytes", "tx_frames", "tx_bytes", "lost", "down_drops")} for p in ports}),
                        flush=True)
                continue
            p = by_fd[fd]
            for _ in range(64):  # drain what is queued on this port
                try:
                    data, addr = p.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:  # ENETDOWN after the port went down: reported once, then fine
                    break
                if addr[2] == PACKET_OUTGOING:  # our own transmission on this port
                    continue
                p.rx_frames += 1
                p.rx_bytes += len(data)
                frame = bytearray(data)
                if not frame[6] & 1:
                    macs[bytes(frame[6:12])] = p
                if p.loss and rng.random() < p.loss:
                    p.lost += 1
                    continue
                fix_udp_checksum(frame)
                d = p.delay + (rng.uniform(-p.jitter, p.jitter) if p.jitter else 0.0)
                if d <= 0.0:
                    forward(frame, p)
                else:
                    seq += 1
                    p.last_release = max(time.monotonic() + d, p.last_release)
                    heapq.heappush(queue, (p.last_release, seq, frame, p))


if __name__ == "__main__":
    main(sys.argv[1:])

"""rclpy helpers shared by every softhand node: QoS of docs/INTERFACE.md, topic table, diagnostics,
rate/jitter meter, parameter declaration from a schema, command line and a quiet main().

A node file stays thin by using these:

    def main(args=None):
        run_node(MyNode, args)          # exits 0 on Ctrl-C, SIGTERM or external shutdown

Only `*_node.py`, `ros_*.py` and `cli.py` import this module (it imports rclpy).
"""
from __future__ import annotations

import argparse
import faulthandler
import gc
import math
import os
import socket
import signal
import sys
import time
from collections import deque
from typing import Callable, Mapping, NoReturn, Optional

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import (ExternalShutdownException, ShutdownException, SingleThreadedExecutor,
                             TimeoutException)
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import remove_ros_args

from softhand_sim.params import ParamError
from softhand_sim.ros.env import discovery_note
from softhand_sim.ros.msgs import diagnostic_array, diagnostic_name, diagnostic_status
from softhand_sim.topics import TOPIC_TYPES

# ------------------------------------------------------------------------------------------- QoS

#: Every softhand publisher (docs/INTERFACE.md): reliable, volatile, keep last 10.
PUB_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                     reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: The state streams (/hand/{side}/intermediate_bones, /hand/{side}/bones, /hand/object_states,
#: /world/object_states): PUB_QOS, but the writer keeps the last 1000 samples (4 s at 250 Hz) to
#: resend to a reliable reader (a recorder; the nodes read them best effort). Across hosts
#: (tests/pipeline/test_across_hosts.py) keep last 10 (40 ms) lost 1-2 % of the intermediate bones
#: to the workstation's recorder on a clean LAN, keep last 250 (1 s) 0.6 % with 2 % packet loss,
#: where a resend comes 0.3-1 s after the loss. Small messages: ~1 MB of history per stream at most.
STREAM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
#: /hand/{side}/skin_mesh publisher and its subscribers: published once, kept for late joiners.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /tracker/{side}/hand_joints subscription: best effort so that any tracker (sensor-data QoS) matches.
SENSOR_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                        reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
#: Subscriptions to state topics (/hand/{side}/bones, /world/object_states, ...): only the latest matters,
#: so best effort: a lost packet is not resent behind newer states. Reliable, a reader delivers in
#: order and waits for the resend of a lost sample (the writer's next heartbeat): with 2 % loss
#: between hosts the reliable recorder got the targets 0.3-1.0 s late at the median, the best-effort
#: sim_node as early as without loss (tests/pipeline/test_across_hosts.py).
LATEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                        reliability=ReliabilityPolicy.BEST_EFFORT, durability=DurabilityPolicy.VOLATILE)
#: Recorder subscriptions: reliable, deep enough to absorb a burst while the writer is busy.
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)

# ---------------------------------------------------------------------------------------- topics

# The topic table (TOPIC_TYPES, LATCHED_TOPICS, ...) lives in softhand_sim.topics: no rclpy there,
# the bag readers use it too.


def message_class(type_name: str):
    """The rclpy message class of 'pkg/msg/Name' (ValueError naming the type if unknown)."""
    parts = type_name.split("/")
    if len(parts) != 3 or parts[1] != "msg":
        raise ValueError(f"message type must look like 'pkg/msg/Name', got {type_name!r}")
    try:
        module = __import__(f"{parts[0]}.msg", fromlist=[parts[2]])
        return getattr(module, parts[2])
    except (ImportError, AttributeError):
        raise ValueError(f"unknown message type {type_name!r} (is its package installed?)") from None


# ----------------------------------------------------------------------------------- rate meter


class RateMeter:
    """Arrival rate and period jitter over the last `window` events (monotonic clock, seconds).

    `tick()` at each event; `stats()` -> dict rate_hz, period_p50_ms, period_p99_ms,
    jitter_p99_ms (|period - median| p99), count (events since start). Pure numpy, no ROS.
    """

    def __init__(self, window: int = 500, clock: Callable[[], float] = time.monotonic):
        self._times = deque(maxlen=int(window) + 1)
        self._clock = clock
        self.count = 0

    def tick(self, t: Optional[float] = None) -> None:
        self._times.append(self._clock() if t is None else float(t))
        self.count += 1

    def stats(self) -> dict:
        t = np.asarray(self._times)
        if t.size < 2:
            return {"rate_hz": 0.0, "period_p50_ms": math.nan, "period_p99_ms": math.nan,
                    "jitter_p99_ms": math.nan, "count": self.count}
        dt = np.diff(t)
        p50 = float(np.median(dt))
        span = float(t[-1] - t[0])
        return {"rate_hz": (t.size - 1) / span if span > 0 else math.inf,
                "period_p50_ms": 1e3 * p50,
                "period_p99_ms": 1e3 * float(np.percentile(dt, 99)),
                "jitter_p99_ms": 1e3 * float(np.percentile(np.abs(dt - p50), 99)),
                "count": self.count}


# ---------------------------------------------------------------------------------- rejections


class RejectionLog:
    """Counts rejected inputs by reason; logs each reason at most once per `period` [s].

    `log(reason, detail)` counts and maybe logs; `counts` (reason -> n) goes into /diagnostics.
    Bad input must never stop a node, and a flood of it must not flood the log either.
    """

    def __init__(self, logger, period: float = 2.0, clock: Callable[[], float] = time.monotonic):
        self._logger = logger
        self._period = float(period)
        self._clock = clock
        self._last = {}
        self.counts = {}

    def log(self, reason: str, detail) -> None:
        self.counts[reason] = self.counts.get(reason, 0) + 1
        now = self._clock()
        if now - self._last.get(reason, -math.inf) > self._period:
            self._last[reason] = now
            self._logger.warning(f"rejected {reason}: {detail} (total {self.counts[reason]})")


# ---------------------------------------------------------------------------------- diagnostics


class DiagnosticsPublisher:
    """Publishes /diagnostics at `period` s from `collect() -> (values dict, level, message)`.

    level is 'ok' | 'warn' | 'error' | 'stale'. The status is named '<node>: <task>'
    (`diagnostic_name`) with the hardware id 'softhand@<host>' unless given.
    An exception in collect() is reported as an ERROR status (with its text), not swallowed.
    """

    def __init__(self, node: Node, collect: Callable[[], tuple], period: float = 1.0,
                 name: Optional[str] = None, topic: str = "/diagnostics", hardware_id: Optional[str] = None):
        self._node = node
        self._collect = collect
        self._name = name or diagnostic_name(node.get_name())
        self._hardware_id = hardware_id or f"softhand@{socket.gethostname()}"
        self._pub = node.create_publisher(message_class(TOPIC_TYPES["/diagnostics"]), topic, PUB_QOS)
        self._timer = node.create_timer(float(period), self.publish_now)

    def publish_now(self) -> None:
        try:
            values, level, message = self._collect()
        except Exception as exc:  # report, do not kill the node over a statistics bug
            values, level, message = {}, "error", f"diagnostics failed: {type(exc).__name__}: {exc}"
            self._node.get_logger().error(message)
        stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(diagnostic_array([diagnostic_status(self._name, values, level, message,
                                                                   hardware_id=self._hardware_id)], stamp))


# ----------------------------------------------------------------------------------- parameters

_PY_TYPES = (bool, int, float, str)


def _spec_fields(name: str, spec):
    """(default, description, min, max) of a schema entry: a plain default or a mapping/object."""
    if isinstance(spec, _PY_TYPES) or isinstance(spec, (list, tuple)):
        return spec, "", None, None
    get = spec.get if isinstance(spec, Mapping) else (lambda k, d=None: getattr(spec, k, d))
    if get("default") is None:
        raise ValueError(f"parameter schema entry {name!r} has no default")
    doc = get("doc") or get("description") or ""
    unit = get("unit")
    desc = f"{doc} [{unit}]" if unit else doc
    lo, hi = get("min"), get("max")
    rng = get("range")
    if rng is not None:
        lo, hi = rng
    return get("default"), desc, lo, hi


def declare_parameters_from_schema(node: Node, schema: Mapping) -> dict:
    """Declare every parameter of `schema` on `node`; return name -> value (after overrides).

    schema: name -> default, or name -> mapping/object with default, doc (or description), unit,
    and optional min/max (or range=(min, max)). Numeric bounds go into the descriptor, so ROS
    refuses an out-of-range `-p name:=value` (InvalidParameterValueException names the parameter).
    """
    values = {}
    for name, spec in schema.items():
        default, desc, lo, hi = _spec_fields(name, spec)
        descriptor = ParameterDescriptor(name=name, description=desc)
        if lo is not None and hi is not None and isinstance(default, float) and not isinstance(default, bool):
            descriptor.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi))]
        elif lo is not None and hi is not None and isinstance(default, int) and not isinstance(default, bool):
            descriptor.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        param = node.declare_parameter(name, default, descriptor)
        values[name] = param.value
    return values


# ------------------------------------------------------------------------------ CLI and main()


def take_pending(subscription, budget_s: float):
    """Messages already waiting in `subscription`'s reader (oldest first), taken while the caller
    has spent less than `budget_s` [s] since this call began.

    The executor hands a subscription one message per wait cycle; a node whose cycles slow down
    under CPU contention (a 250 Hz timer catching up) then falls behind a 100 Hz topic until its
    keep-last queue overflows (measured: 15 of 1171 tracker frames lost on a loaded machine). A
    callback that takes the backlog as well stays current; the budget keeps a flood of messages
    from starving the node's timers. Uses the take the executor itself uses (rclpy
    executors._take_subscription).
    """
    deadline = time.perf_counter() + budget_s
    while time.perf_counter() < deadline:
        with subscription.handle:
            taken = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        if taken is None:
            return
        yield taken[0]


def split_cli(parser: argparse.ArgumentParser, args=None):
    """Parse the node's own flags, leaving `--ros-args ...` for rclpy.

    Returns (namespace, full argv for rclpy.init). `--help` prints and exits 0 before rclpy
    starts; a bad flag exits 2 with argparse's message on stderr, and so do ROS arguments rcl
    refuses (a params file missing or not YAML), with rcl's message.
    """
    argv = list(sys.argv if args is None else args)
    try:
        own = remove_ros_args(args=argv)[1:]
    except RuntimeError as exc:  # rcl's RCLInvalidROSArgsError: e.g. a params file it cannot read
        # rcl appends where in its C sources it failed (", at /project/src/..."): not the user's concern
        parser.exit(2, f"{parser.prog}: error: {str(exc).split(', at /')[0].strip()}\n")
    return parser.parse_args(own), argv


def run_node(make_node: Callable[..., Node], args=None, init_args=None, drain_s: float = 0.0) -> int:
    """init, build the node, spin until stopped, shut down quietly; returns the exit code.

    SIGINT (Ctrl-C) and SIGTERM set a stop flag (rclpy's own handlers are not installed, so the
    context stays alive for the shutdown path); spin then ends within ~0.1 s. With drain_s > 0
    the executor first runs whatever had already arrived (callbacks still run; `_drain`), at most
    drain_s -- a recorder loses nothing that reached its process. Then the
    node's `close()` runs if it has one (flushing files), the node is destroyed and rclpy shut
    down. An external rclpy.shutdown() also ends spin quietly. A callback may raise NodeExit(code)
    to stop with that exit code. A ParamError while building the node (a bad parameter) prints
    one line naming the key and value and returns 1, with no traceback.
    """
    stop = {"signal": None}

    def on_signal(signum, frame):
        stop["signal"] = signum

    # SIGUSR1 prints every thread's Python stack to stderr (the node's log) and goes on: the demo
    # asks for it before it kills a node that did not stop in time, so the log says where it hung.
    faulthandler.register(signal.SIGUSR1, all_threads=True)

    rclpy.init(args=init_args if init_args is not None else args,
               signal_handler_options=SignalHandlerOptions.NO)
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    node = None
    code = 0
    executor = make_executor()
    try:
        node = make_node()
        note = discovery_note()
        if note is not None:
            (node.get_logger().warning if note[0] == "warn" else node.get_logger().info)(note[1])
        executor.add_node(node)
        # What is made so far (rclpy, numba's dispatchers, the model) lives for the whole run:
        # frozen, the collector's full passes no longer walk it. sim_node holds ~146k tracked
        # objects after its warm-up, and its first full pass came a moment after it was ready
        # and stalled it 45-63 ms (measured with gc.callbacks over two demos)
        gc.collect()
        gc.freeze()
        while stop["signal"] is None and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        if drain_s > 0 and rclpy.ok():
            _drain(executor, drain_s)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except NodeExit as exc:
        code = exc.code
        if str(exc):
            print(str(exc), file=sys.stderr, flush=True)
    except ParamError as exc:
        print(f"error: {exc}", file=sys.stderr, flush=True)
        code = 1
    finally:
        for s in old:  # a second Ctrl-C must not cut close() short
            signal.signal(s, signal.SIG_IGN)
        if node is not None:
            close = getattr(node, "close", None)
            if callable(close):
                close()
        # rclpy's teardown takes well under a second; once (a fresh clone's make test) a
        # tracking_node did not end within the demo's 10 s: a stalled teardown prints where it
        # stalls into the node's log after TEARDOWN_DUMP_S (and SIGUSR1 prints it at any time)
        faulthandler.dump_traceback_later(TEARDOWN_DUMP_S, exit=False)
        if node is not None:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown(timeout_sec=0)
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()
    return code


#: [s] a node's rclpy teardown taking longer than this prints every thread's stack (run_node)
TEARDOWN_DUMP_S = 5.0
#: [s] the drain's second marker is posted at least this long after its first (_drain)
DRAIN_GAP_S = 0.1


#: The executor of every node (run_node): "events" (default) or "single", from SOFTHAND_EXECUTOR.
EXECUTOR_ENV = "SOFTHAND_EXECUTOR"


def make_executor():
    """rclpy's EventsExecutor, or its SingleThreadedExecutor with SOFTHAND_EXECUTOR=single.

    The events executor dispatches from C++: a node with a 250 Hz timer that publishes one
    PoseArray took 8 % of a core with it, 22 % with the single-threaded one, which rebuilds its
    wait set in Python on every wake-up. On two shared cores that was the difference between a
    tracking node that keeps up and one that takes tracker frames up to 200 ms late.
    The single-threaded executor stays selectable to compare and as a fallback.
    """
    kind = os.environ.get(EXECUTOR_ENV, "events") or "events"
    if kind == "single":
        return SingleThreadedExecutor()
    if kind != "events":
        raise ValueError(f"{EXECUTOR_ENV} must be 'events' or 'single', got {kind!r}")
    return EventsExecutor()


def _drain(executor, budget_s: float) -> None:
    """Run what already arrived, within the budget.

    The single-threaded executor says when a wait found nothing. The events executor runs its work
    in the order it arrived (one asio queue), so a task posted now runs after every message that
    reached the process before it: the drain spins until such a marker has run, then posts a
    second one at least DRAIN_GAP_S after the first (what DDS was still handing over at the stop).
    Waiting instead for the messages written to stay put over a few spins never ended while the
    recorded nodes kept publishing: every recorder stop spun its whole 2 s budget (3.7 s in all
    to stop a recorder beside the running node set).
    """
    deadline = time.monotonic() + budget_s
    if not isinstance(executor, SingleThreadedExecutor):
        gap_end = time.monotonic() + DRAIN_GAP_S
        _spin_past_marker(executor, deadline)
        while time.monotonic() < min(gap_end, deadline):
            executor.spin_once(timeout_sec=0.01)
        _spin_past_marker(executor, deadline)
        return
    while time.monotonic() < deadline:
        try:
            handler, _entity, _node = executor.wait_for_ready_callbacks(timeout_sec=0.05)
        except (TimeoutException, ShutdownException):
            return
        handler()
        if handler.exception() is not None:
            raise handler.exception()


def _spin_past_marker(executor, deadline: float) -> None:
    """Post a task to the events executor and spin until it has run (or the deadline): everything
    queued before it has run too."""
    done = []
    executor.create_task(lambda: done.append(True))
    while not done and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)


class NodeExit(Exception):
    """Raised from a callback to leave spin with an exit code (e.g. play_node at the end of a bag)."""

    def __init__(self, code: int = 0, message: str = ""):
        super().__init__(message)
        self.code = int(code)


def fail(message: str, code: int = 1) -> NoReturn:
    """Print `message` on stderr (no traceback) and exit with `code`."""
    print(f"error: {message}", file=sys.stderr, flush=True)
    raise SystemExit(code)

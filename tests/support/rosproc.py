"""Test helpers for real ROS 2 processes: start nodes as subprocesses, listen and talk in-process.

    def test_x(ros_env, tmp_path):
        with RosGraph(ros_env) as g:                      # in-process rclpy on the test's domain
            sub = g.listen("/hand/right/bones", PoseArray)
            proc = g.start(["softhand-play", str(bag)])   # subprocess with ros_env
            g.wait_until(lambda: len(sub.msgs) >= 10, 20, "bones")
            assert proc.stop() == 0                       # SIGINT, exit code
        # every process still alive is killed on exit, whatever happened

Every subprocess gets the env of the `ros_env` fixture (LOCALHOST discovery, own ROS_DOMAIN_ID);
the in-process context uses the same domain id explicitly. Process output goes to files (no
pipe can fill up and block a node) and is returned by `output()` for assertions and failure
messages.
"""
from __future__ import annotations

import os
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from rclpy.qos import QoSProfile

from softhand_sim.ros.common import PUB_QOS

#: A test listener's QoS: the nodes' (reliable, volatile) with a deep reader history. With keep last
#: 10 a reliable reader still drops the oldest samples when more than 10 arrive before this
#: process's executor thread takes them (a busy test process: play_node at 100 Hz lost a few of 41
#: frames once in a fresh clone's run), which is the listener's loss, not the node's.
LISTEN_QOS = QoSProfile(history=PUB_QOS.history, depth=1000, reliability=PUB_QOS.reliability,
                        durability=PUB_QOS.durability)

VENV_BIN = Path(__file__).resolve().parents[2] / ".venv" / "bin"


def node_diagnostics(msgs, node: str) -> list:
    """The /diagnostics values (dicts) of `node`'s statuses in the DiagnosticArray messages `msgs`
    (a collector's list, read as it stands: a spinning thread may append), oldest first."""
    from softhand_sim.ros.msgs import diagnostic_values, status_node
    return [diagnostic_values(st) for m in list(msgs) for st in m.status if status_node(st.name) == node]


def latest_node_diagnostics(msgs, node: str):
    """The newest /diagnostics values (dict) of `node` in `msgs`, or None before its first."""
    from softhand_sim.ros.msgs import diagnostic_values, status_node
    for m in reversed(list(msgs)):
        for st in m.status:
            if status_node(st.name) == node:
                return diagnostic_values(st)
    return None


class RosProc:
    """One node subprocess; output in a temp file; stop() sends a signal and returns the exit code."""

    def __init__(self, cmd, env, cwd=None):
        if isinstance(cmd, str):
            raise TypeError("cmd must be a list of arguments")
        cmd = list(cmd)
        exe = VENV_BIN / cmd[0]
        if exe.exists():
            cmd[0] = str(exe)
        self.cmd = cmd
        self._final_output = None
        self._log = tempfile.NamedTemporaryFile(prefix="rosproc_", suffix=".log", delete=False)
        self.popen = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=self._log, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def wait(self, timeout: float) -> int:
        """Exit code after waiting up to `timeout` s (AssertionError with the output if still running)."""
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.cmd[0]} still running after {timeout} s\n{self.output()}") from None

    def stop(self, sig=signal.SIGINT, timeout: float = 15.0) -> int:
        """Send `sig` and return the exit code (kills and fails if it does not exit within `timeout`)."""
        if self.alive():
            self.popen.send_signal(sig)
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.popen.send_signal(signal.SIGUSR1)  # a node's Python stacks into its output (run_node)
            time.sleep(0.5)
            self.kill()
            raise AssertionError(f"{self.cmd[0]} ignored signal {sig} for {timeout} s\n{self.output()}") from None

    def kill(self) -> None:
        if self.alive():
            self.popen.kill()
            self.popen.wait(timeout=10)

    def output(self) -> str:
        """Everything the process wrote to stdout and stderr so far (kept after cleanup)."""
        if self._final_output is not None:
            return self._final_output
        self._log.flush()
        return Path(self._log.name).read_text(errors="replace")

    def cleanup(self) -> None:
        """Kill if still running, keep the output text, remove the log file."""
        if self._final_output is not None:
            return
        self.kill()
        self._final_output = self.output()
        self._log.close()
        try:
            os.unlink(self._log.name)
        except OSError:
            pass


class Collector:
    """Messages received on one topic with their receive times (time.monotonic)."""

    def __init__(self):
        self.msgs = []
        self.times = []
        self._lock = threading.Lock()

    def __call__(self, msg):
        with self._lock:
            self.times.append(time.monotonic())
            self.msgs.append(msg)

    def __len__(self):
        return len(self.msgs)


class RosGraph:
    """In-process rclpy (own context, the test's domain) spinning in a thread, plus subprocess bookkeeping."""

    def __init__(self, env: dict, node_name: str = "test_probe"):
        self.env = env
        self.procs: list[RosProc] = []
        self.context = Context()
        rclpy.init(context=self.context, domain_id=int(env["ROS_DOMAIN_ID"]))
        self.node = rclpy.create_node(node_name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while not self._stop.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.05)
            except Exception:
                if self._stop.is_set() or not self.context.ok():
                    break
                raise

    # -- processes
    def start(self, cmd, cwd=None) -> RosProc:
        proc = RosProc(cmd, self.env, cwd=cwd)
        self.procs.append(proc)
        return proc

    # -- topics
    def listen(self, topic: str, msg_type, qos=LISTEN_QOS) -> Collector:
        col = Collector()
        self.node.create_subscription(msg_type, topic, col, qos)
        return col

    def publisher(self, topic: str, msg_type, qos=PUB_QOS):
        return self.node.create_publisher(msg_type, topic, qos)

    def wait_until(self, predicate, timeout: float, what: str, proc: RosProc | None = None) -> None:
        """Poll `predicate` until true; AssertionError naming `what` (and proc output) on timeout."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                extra = f"\n--- {proc.cmd[0]} output ---\n{proc.output()}" if proc is not None else ""
                raise AssertionError(f"timed out after {timeout} s waiting for {what}{extra}")
            if proc is not None and not proc.alive():
                raise AssertionError(f"{proc.cmd[0]} exited ({proc.popen.returncode}) while waiting for "
                                     f"{what}\n{proc.output()}")
            time.sleep(0.02)

    def wait_matched(self, pub, count: int = 1, timeout: float = 20.0, proc: RosProc | None = None) -> None:
        """Wait until `pub` has `count` matched subscriptions (discovery done: publish is heard)."""
        self.wait_until(lambda: pub.get_subscription_count() >= count, timeout,
                        f"{count} subscriber(s) on {pub.topic_name}", proc)

    def close(self) -> None:
        for proc in self.procs:
            proc.cleanup()
        self._stop.set()
        self._thread.join(timeout=5)
        self.executor.shutdown(timeout_sec=1)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

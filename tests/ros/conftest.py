"""Fixtures of the ROS tests: a real roscore on a free loopback port, this process as a ROS
node, real frames, and helpers to wait for messages. Every test here is skipped, with the
reason, where ROS 1 (rospy, roscore) is not installed."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from tests.images import clip_frames
from tests.isolated import ROOT as REPO

CASTLE = REPO.parent.parent / "shared" / "data" / "real" / "castle_simu"
CASTLE = CASTLE if CASTLE.is_dir() else REPO.parent / "shared" / "data" / "real" / "castle_simu"
#: Seconds any wait in these tests may take before it fails (no test hangs).
WAIT = 20.0


def _ros_missing() -> str | None:
    from warpvx.errors import UnsupportedError
    from warpvx.ros import import_rospy

    try:
        import_rospy()
    except UnsupportedError as exc:
        return str(exc)
    if shutil.which("roscore") is None:
        return "ROS 1: the roscore command is not installed (apt-get install ros-core)"
    return None


@pytest.fixture(scope="session")
def ros_available():
    """Skip (with the reason) where ROS 1 is not installed."""
    reason = _ros_missing()
    if reason:
        pytest.skip(reason)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_roscore(port: int, log_path) -> subprocess.Popen:
    """A roscore on loopback ``port`` (its own process group, output in ``log_path``), once its
    master answers; fails the test if it does not within :data:`WAIT` s."""
    import rosgraph

    with open(log_path, "a") as log:
        proc = subprocess.Popen(["roscore", "-p", str(port)], stdout=log, stderr=subprocess.STDOUT,
                                start_new_session=True)
    deadline = time.monotonic() + WAIT
    while not rosgraph.is_master_online(f"http://127.0.0.1:{port}"):
        if proc.poll() is not None or time.monotonic() > deadline:
            kill_roscore(proc)
            pytest.fail(f"roscore did not start on port {port}: {log_path.read_text()[-2000:]}")
        time.sleep(0.1)
    return proc


def _descendants(pid: int) -> list[int]:
    kids = [int(p) for p in subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)],
                                           capture_output=True, text=True).stdout.split()]
    return kids + [d for k in kids for d in _descendants(k)]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def kill_roscore(proc, sig=signal.SIGINT):
    """Stop a roscore and its children (rosmaster, rosout: roslaunch starts each in a session
    of its own) with ``sig`` (SIGKILL: a crash), and wait until all are gone; SIGKILL if that
    hangs."""
    family = _descendants(proc.pid)
    for send in (sig, signal.SIGKILL):
        if proc.poll() is None:
            os.killpg(proc.pid, send)
        for pid in family:
            if _alive(pid):
                os.kill(pid, send)
        deadline = time.monotonic() + WAIT
        while (proc.poll() is None or any(map(_alive, family))) and time.monotonic() < deadline:
            time.sleep(0.05)
        if proc.poll() is not None and not any(map(_alive, family)):
            return


@pytest.fixture(scope="session")
def roscore(ros_available, tmp_path_factory):
    """A real roscore on a free loopback port; the environment points ROS at it (this process
    and the node processes tests start). Yields the master URI; stopped with SIGINT (its
    children with it) at the end of the session."""
    port = _free_port()
    uri = f"http://127.0.0.1:{port}"
    mp = pytest.MonkeyPatch()
    mp.setenv("ROS_MASTER_URI", uri)
    mp.setenv("ROS_HOSTNAME", "127.0.0.1")  # loopback only
    mp.delenv("ROS_IP", raising=False)
    mp.setenv("ROS_HOME", str(tmp_path_factory.mktemp("ros_home")))
    mp.setenv("WARPVX_CACHE_DIR", str(tmp_path_factory.mktemp("calibration")))
    try:
        proc = start_roscore(port, tmp_path_factory.mktemp("roscore") / "roscore.log")
        yield uri
        kill_roscore(proc)
    finally:
        mp.undo()


@pytest.fixture(scope="session")
def rospy(roscore):
    """rospy, with this test process initialised as node ``/warpvx_test`` (signals left to
    pytest); shut down at the end of the session."""
    from warpvx.ros import import_rospy

    rospy = import_rospy()
    rospy.init_node("warpvx_test", anonymous=True, disable_signals=True)
    yield rospy
    rospy.signal_shutdown("tests done")


@pytest.fixture(scope="session")
def bikes():
    """The first 12 frames of the bundled hand-held clip at 320x136 (BGR uint8)."""
    return clip_frames(12)


@pytest.fixture(scope="session")
def castle(bikes):
    """The first 10 frames of the castle sequence (gray uint8 480x640) and its K (float64
    3x3); where the shared data is absent (a bare CI checkout), the bundled clip's frames in
    gray, doubled to 640x272 so that ORB-SLAM2's 8 levels fit, with a nominal K (focal length =
    width)."""
    if not CASTLE.is_dir():
        frames = [cv2.resize(cv2.cvtColor(f, cv2.COLOR_BGR2GRAY), None, fx=2, fy=2,
                             interpolation=cv2.INTER_LINEAR) for f in bikes[:10]]
        h, w = frames[0].shape
        return frames, np.array([[w, 0, w / 2], [0, w, h / 2], [0, 0, 1]], np.float64)
    fx, fy, cx, cy, _, _ = np.loadtxt(CASTLE / "intrinsics.txt")
    frames = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
              for p in sorted((CASTLE / "image_0").glob("*.png"))[:10]]
    return frames, np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])


class Inbox:
    """Messages of one topic as they arrive; :meth:`wait` blocks until ``n`` came (or fails)."""

    def __init__(self, rospy, topic, msg_class):
        self.messages = []
        self._cond = threading.Condition()
        self.sub = rospy.Subscriber(topic, msg_class, self._on, queue_size=None, buff_size=1 << 24)

    def _on(self, msg):
        with self._cond:
            self.messages.append(msg)
            self._cond.notify_all()

    def wait(self, n, timeout=WAIT):
        with self._cond:
            if not self._cond.wait_for(lambda: len(self.messages) >= n, timeout):
                pytest.fail(f"{self.sub.resolved_name}: {len(self.messages)} of {n} messages "
                            f"within {timeout} s")
            return list(self.messages)


def wait_connected(*endpoints, timeout=WAIT):
    """Wait until every publisher/subscriber has a connection (so nothing sent is lost)."""
    deadline = time.monotonic() + timeout
    for e in endpoints:
        while e.get_num_connections() == 0:
            if time.monotonic() > deadline:
                pytest.fail(f"{e.resolved_name}: no connection within {timeout} s")
            time.sleep(0.02)


@pytest.fixture
def node_process(roscore):
    """Start ``warpvx <args>`` as a ROS node process (or ``python -c code <args>``; ``env``:
    variables over this process' environment); stopped with SIGINT at teardown. Its output so far is in ``proc.lines``
    (:func:`wait_output`), all of it in ``proc.output`` once stopped (:func:`stop`)."""
    procs = []

    def start(*args, env=None, code=None):
        run = ("-c", code) if code else ("-m", "warpvx")
        proc = subprocess.Popen([sys.executable, *run, *args], cwd=REPO,
                                env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})},
                                text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        proc.lines = []
        proc.reader = threading.Thread(target=lambda: proc.lines.extend(proc.stdout), daemon=True)
        proc.reader.start()
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        print(f"--- output of {proc.args[2:]}:\n{stop(proc)[-3000:]}")  # shown when a test fails


def wait_output(proc, text, timeout=WAIT):
    """Wait until a line of ``proc``'s output (a :func:`node_process`) contains ``text``."""
    deadline = time.monotonic() + timeout
    while not any(text in line for line in list(proc.lines)):
        if time.monotonic() > deadline or proc.poll() is not None and not proc.reader.is_alive():
            pytest.fail(f"no {text!r} in the node's output within {timeout} s:\n"
                        f"{''.join(proc.lines)[-3000:]}")
        time.sleep(0.05)


def stop(proc, timeout=WAIT):
    """SIGINT a node process and collect its output in ``proc.output`` (killed if it hangs)."""
    if getattr(proc, "output", None) is not None:
        return proc.output
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout)
        hung = False
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        hung = True
    proc.reader.join(timeout)
    proc.output = "".join(proc.lines)
    if hung:
        pytest.fail(f"node did not stop within {timeout} s on SIGINT:\n{proc.output[-3000:]}")
    return proc.output

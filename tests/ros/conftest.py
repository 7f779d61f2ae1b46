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

from tests.isolated import ROOT as REPO

CLIP = REPO / "warpvx" / "data" / "bikes_shaky.mp4"
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


@pytest.fixture(scope="session")
def roscore(ros_available, tmp_path_factory):
    """A real roscore on a free loopback port; the environment points ROS at it (this process
    and the node processes tests start). Yields the master URI; stopped with SIGINT (its
    children with it) at the end of the session."""
    from warpvx.ros import import_rospy

    import_rospy()
    import rosgraph

    port = _free_port()
    uri = f"http://127.0.0.1:{port}"
    mp = pytest.MonkeyPatch()
    mp.setenv("ROS_MASTER_URI", uri)
    mp.setenv("ROS_HOSTNAME", "127.0.0.1")  # loopback only
    mp.delenv("ROS_IP", raising=False)
    mp.setenv("ROS_HOME", str(tmp_path_factory.mktemp("ros_home")))
    mp.setenv("WARPVX_CACHE_DIR", str(tmp_path_factory.mktemp("calibration")))
    log = open(tmp_path_factory.mktemp("roscore") / "roscore.log", "w+")
    proc = subprocess.Popen(["roscore", "-p", str(port)], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    try:
        deadline = time.monotonic() + WAIT
        while not rosgraph.is_master_online(uri):
            if proc.poll() is not None or time.monotonic() > deadline:
                log.seek(0)
                pytest.fail(f"roscore did not start on port {port}: {log.read()[-2000:]}")
            time.sleep(0.1)
        yield uri
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(WAIT)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        log.close()
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
    cap = cv2.VideoCapture(str(CLIP))
    frames = []
    while len(frames) < 12:
        ok, frame = cap.read()
        assert ok, "the bundled clip is shorter than 12 frames"
        frames.append(cv2.resize(frame, (320, 136), interpolation=cv2.INTER_AREA))
    return frames


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
    """Start ``warpvx <args>`` as a ROS node process; stopped with SIGINT at teardown (its
    output is then in ``proc.output``)."""
    procs = []

    def start(*args):
        proc = subprocess.Popen([sys.executable, "-m", "warpvx", *args], cwd=REPO,
                                env={**os.environ, "PYTHONPATH": str(REPO)}, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        procs.append(proc)
        return proc

    yield start
    for proc in procs:
        print(f"--- output of {proc.args[2:]}:\n{stop(proc)[-3000:]}")  # shown when a test fails


def stop(proc, timeout=WAIT):
    """SIGINT a node process and collect its output in ``proc.output`` (killed if it hangs)."""
    if getattr(proc, "output", None) is not None:
        return proc.output
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.output = proc.communicate(timeout=timeout)[0]
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.output = proc.communicate()[0]
        pytest.fail(f"node did not stop within {timeout} s on SIGINT:\n{proc.output[-3000:]}")
    return proc.output

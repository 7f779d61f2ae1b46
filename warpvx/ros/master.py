"""A watchdog for the ROS master (roscore) a node registered with.

rospy keeps running when its master goes away: topics already connected keep flowing (they are
peer-to-peer), but nothing new can connect and nothing says so. :class:`MasterWatchdog` asks
the master for its pid every ``period`` seconds, each call bounded by a socket timeout so a
master that hangs (or a host that vanished) cannot block it, and logs one line when the master
becomes unreachable and one when it answers again. A master that answers with another pid was
restarted: it lost this node's registrations, which rospy does not renew, so the line says the
node must be restarted to reconnect its topics.
"""

from __future__ import annotations

import threading
import xmlrpc.client

from ..check import check_float
from ._env import import_rospy


class _TimeoutTransport(xmlrpc.client.Transport):
    """An XML-RPC transport whose connections time out after ``timeout`` seconds."""

    def __init__(self, timeout: float):
        super().__init__()
        self._timeout = timeout

    def make_connection(self, host):
        conn = super().make_connection(host)
        conn.timeout = self._timeout  # used by connect() and every later socket operation
        return conn


class MasterWatchdog:
    """Log when the ROS master of this node becomes unreachable, and when it is back.

    Parameters
    ----------
    period : float
        Seconds between checks (> 0); each check waits at most ``period`` seconds for an answer.

    A daemon thread runs from construction until :meth:`close` (or rospy's shutdown), so it
    never keeps a process alive. ``reachable`` is the latest check's result.
    """

    def __init__(self, period: float = 2.0):
        self.period = check_float(period, "period", min_value=0, strict_min=True)
        self.rospy = rospy = import_rospy()
        import rosgraph

        self.uri = rosgraph.get_master_uri()
        self._caller = rospy.get_caller_id()
        self._proxy = xmlrpc.client.ServerProxy(self.uri, transport=_TimeoutTransport(self.period))
        self._stop = threading.Event()
        self.reachable, self._pid = True, self._master_pid()
        self._thread = threading.Thread(target=self._run, name="warpvx-ros-master", daemon=True)
        self._thread.start()

    def _master_pid(self):
        """The master's pid, or None when it does not answer within the period."""
        try:
            code, _, pid = self._proxy.getPid(self._caller)
        except (OSError, xmlrpc.client.Error):
            return None
        return pid if code == 1 else None

    def _run(self):
        while not self._stop.wait(self.period) and not self.rospy.is_shutdown():
            pid = self._master_pid()
            if pid is None and self.reachable:
                self.rospy.logerr(f"warpvx: ROS master at {self.uri} unreachable (roscore gone?); "
                                  f"connected topics go on, no new connection can be made")
            elif pid is not None and not self.reachable:
                restarted = "" if pid == self._pid or self._pid is None else (
                    f", but it was restarted (pid {self._pid} -> {pid}) and lost this node's "
                    f"registrations: restart the node to reconnect its topics")
                self.rospy.logwarn(f"warpvx: ROS master at {self.uri} reachable again{restarted}")
            self.reachable = pid is not None
            self._pid = pid if pid is not None else self._pid

    def close(self, timeout: float | None = None):
        """Stop checking (waits for a check in progress, at most ``timeout`` s). Idempotent."""
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(self.period + 1 if timeout is None else timeout)

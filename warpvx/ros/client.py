"""Client model (thesis §4.6, Fig. 4.9): a graph runs per message of a camera topic.

A subscriber callback converts each image (a view of the message, :mod:`warpvx.ros.convert`)
and puts it in a bounded :class:`FrameQueue`; one processing thread feeds the queue to the
graph's :meth:`~warpvx.Graph.stream` (``depth`` frames in flight) and publishes each frame's
outputs. The camera never waits for the graph: when frames arrive faster than the graph runs,
the queue drops its oldest frame and counts it, which is how the thesis simulates live capture
(frames skipped at the processing rate). Publishers are asynchronous (rospy's ``queue_size``),
so a slow downstream subscriber does not stall the processing thread either.

Bad input never stops the node: a frame that cannot be converted (an unsupported encoding), or
that the graph refuses (an image size that changed mid-stream), is counted as rejected and
logged (at most every few seconds per message); a node that raises is logged and the stream
restarts with the next frame; a silent camera topic (a dead publisher) is logged once per
silence.
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from typing import Callable

from ..errors import WarpvxError, WarpvxValueError
from ._env import import_rospy, msg as _msg
from .convert import array_to_image, camera_matrix, check_encoding, image_to_array, matrix_to_multiarray

#: Seconds between repeats of one log line about rejected frames.
LOG_PERIOD = 5.0


@dataclasses.dataclass(frozen=True)
class Topic:
    """A graph input or output bound to a ROS topic.

    ``msg_type`` is (package, message), e.g. ``("sensor_msgs", "Image")``. ``convert`` maps a
    message to the input's value (subscriptions), or ``(value, header)`` to a message
    (publications; None publishes nothing).
    """

    topic: str
    msg_type: tuple
    convert: Callable


def image_input(topic: str, encoding: str = "bgr8") -> Topic:
    """Subscribe ``topic`` (sensor_msgs/Image); the input gets uint8 pixels in ``encoding``
    (a view of the message when it has that encoding, else one cvtColor)."""
    check_encoding(encoding)
    return Topic(topic, ("sensor_msgs", "Image"), lambda m: image_to_array(m, encoding))


def camera_info_input(topic: str) -> Topic:
    """Subscribe ``topic`` (sensor_msgs/CameraInfo); the input gets K, float64 3x3."""
    return Topic(topic, ("sensor_msgs", "CameraInfo"), camera_matrix)


def image_output(topic: str, encoding: str | None = None) -> Topic:
    """Publish an image output (uint8 HxW or HxWx3) on ``topic`` as sensor_msgs/Image,
    stamped with its input frame's header."""
    if encoding is not None:
        check_encoding(encoding)
    return Topic(topic, ("sensor_msgs", "Image"),
                 lambda value, header: array_to_image(value, encoding, header))


def matrix_output(topic: str) -> Topic:
    """Publish a 2-D float output (a 3x3 warp, say) on ``topic`` as std_msgs/Float64MultiArray."""
    return Topic(topic, ("std_msgs", "Float64MultiArray"), lambda value, header: matrix_to_multiarray(value))


@dataclasses.dataclass
class FrameStats:
    """Frame accounting of a client: ``received`` camera messages, ``rejected`` (unconvertible,
    refused by the graph, or waiting for another input), ``dropped`` (the queue was full: skipped
    at the processing rate), ``processed`` (outputs came back from the graph), ``published``
    (processed and past the output lag), ``errors`` (frames lost to a node that raised)."""

    received: int = 0
    rejected: int = 0
    dropped: int = 0
    processed: int = 0
    published: int = 0
    errors: int = 0
    started: float = dataclasses.field(default_factory=time.monotonic)

    def summary(self) -> str:
        """One line: the counts, the dropped share and the processing rate (frames/s)."""
        elapsed = max(time.monotonic() - self.started, 1e-9)
        share = self.dropped / self.received if self.received else 0.0
        return (f"received {self.received}, processed {self.processed} ({self.processed / elapsed:.1f} "
                f"FPS), published {self.published}, dropped {self.dropped} ({share:.1%}, skipped at "
                f"the processing rate), rejected {self.rejected}, lost to errors {self.errors}")


class FrameQueue:
    """A bounded FIFO between a subscriber callback and the processing thread: :meth:`put`
    never blocks and, when full, drops the oldest item (the thesis' live-capture skip)."""

    CLOSED = object()

    def __init__(self, maxsize: int):
        if isinstance(maxsize, bool) or not isinstance(maxsize, int) or maxsize < 1:
            raise WarpvxValueError(f"queue_size: expected an int >= 1, got {maxsize!r}")
        self._items = deque()
        self._maxsize = maxsize
        self._cond = threading.Condition()
        self._closed = False

    def put(self, item) -> bool:
        """Append ``item``; True when the oldest item was dropped to make room."""
        with self._cond:
            dropped = len(self._items) >= self._maxsize
            if dropped:
                self._items.popleft()
            self._items.append(item)
            self._cond.notify()
            return dropped

    def get(self, timeout: float | None = None):
        """The oldest item; None after ``timeout`` seconds without one; :attr:`CLOSED` once
        :meth:`close` was called (queued items are discarded)."""
        with self._cond:
            self._cond.wait_for(lambda: self._items or self._closed, timeout)
            if self._closed:
                return self.CLOSED
            return self._items.popleft() if self._items else None

    def close(self):
        with self._cond:
            self._closed = True
            self._cond.notify_all()


class GraphClient:
    """Run a graph per message of a camera topic and publish its outputs (the client model).

    Parameters
    ----------
    graph : warpvx.Graph or callable
        The graph, or ``make(first_frame) -> Graph`` called with the first frame's inputs (a
        dict name -> array) when its size is known.
    inputs : dict
        Graph input name -> :class:`Topic` (:func:`image_input`, :func:`camera_info_input`).
        The first is the camera: each of its messages is a frame. The others hold their latest
        message (camera info); frames are rejected until each has one. A name that is not an
        input of the graph goes to ``post`` only.
    outputs : dict
        Name -> :class:`Topic` (:func:`image_output`, :func:`matrix_output`): a graph output
        or a key that ``post`` returns.
    constants : dict, optional
        Graph input name -> value given with every frame.
    post : callable, optional
        ``post(outputs, inputs, header) -> dict`` run on each frame's outputs (and the inputs
        the graph got) in frame order in the processing thread (tracking after extraction,
        say); its keys join the outputs.
    queue_size : int
        Frames waiting for the graph; when full the oldest is dropped (1: always the latest
        frame, as a live camera).
    depth : int
        Frames in flight in the graph (:meth:`~warpvx.Graph.stream`).
    lag : int
        The graph's output of frame k shows frame k - lag (a centred smoothing window): it is
        stamped with that frame's header, and the first ``lag`` outputs are not published.
    watchdog : float
        Seconds without a camera frame before a warning that the publisher may be gone.
    publish_queue : int
        Messages each publisher holds for a slow subscriber before rospy drops its oldest.
    dropped_topic : str or None
        Where the cumulative dropped count is published (std_msgs/UInt64) after each frame.
    """

    def __init__(self, graph, inputs: dict, outputs: dict, *, constants=None, post=None,
                 queue_size: int = 2, depth: int = 2, lag: int = 0, watchdog: float = 5.0,
                 publish_queue: int = 10, dropped_topic: str | None = "~dropped"):
        if not inputs:
            raise WarpvxValueError("inputs: expected at least one input topic (the camera)")
        self.rospy = rospy = import_rospy()
        self._make = graph if callable(graph) and not hasattr(graph, "stream") else (lambda _: graph)
        self.graph = None
        self.depth, self.lag, self.watchdog = depth, lag, watchdog
        self._post = post
        self._constants = dict(constants or {})
        self._outputs = outputs
        self._queue = FrameQueue(queue_size)
        self._in_flight = deque()  # (header, inputs) of the frames in the graph, in order
        self._latest = {}
        self._latest_lock = threading.Lock()
        self.stats = FrameStats()
        self._stats_lock = threading.Lock()
        (self._camera_name, self._camera), *others = inputs.items()
        self._subs = [rospy.Subscriber(self._camera.topic, _msg(*self._camera.msg_type),
                                       self._on_camera, queue_size=None, buff_size=1 << 24)]
        self._camera_topic = self._subs[0].resolved_name  # "image" logs as "/camera/image_raw"
        self._subs += [rospy.Subscriber(t.topic, _msg(*t.msg_type), self._on_latest, (name, t))
                       for name, t in others]
        self._others = {name: t.topic for name, t in others}
        self._pubs = {name: rospy.Publisher(t.topic, _msg(*t.msg_type), queue_size=publish_queue)
                      for name, t in outputs.items()}
        self._dropped_pub = (rospy.Publisher(dropped_topic, _msg("std_msgs", "UInt64"),
                                             queue_size=publish_queue)
                             if dropped_topic else None)
        self._thread = threading.Thread(target=self._run, name="warpvx-ros-client", daemon=True)
        self._thread.start()

    # ---------------------------------------------------------------- subscriber side

    def _on_latest(self, msg, binding):
        name, topic = binding
        try:
            value = topic.convert(msg)
        except WarpvxError as exc:
            self.rospy.logerr_throttle_identical(LOG_PERIOD, f"warpvx: {topic.topic}: message ignored: {exc}")
            return
        with self._latest_lock:
            self._latest[name] = value

    def _on_camera(self, msg):
        self._count("received")
        try:
            frame = {self._camera_name: self._camera.convert(msg)}
        except WarpvxError as exc:
            self._reject(f"{self._camera_topic}: frame rejected: {exc}")
            return
        with self._latest_lock:
            missing = [t for n, t in self._others.items() if n not in self._latest]
            frame.update(self._latest)
        if missing:
            self._reject(f"{self._camera_topic}: frame rejected: waiting for a first message on "
                         f"{missing}")
            return
        frame.update(self._constants)
        if self._queue.put((msg.header, frame)):
            self._count("dropped")

    def _count(self, field, n=1):
        with self._stats_lock:  # the callback and the processing thread both count
            setattr(self.stats, field, getattr(self.stats, field) + n)

    def _reject(self, text):
        self._count("rejected")
        self.rospy.logerr_throttle_identical(LOG_PERIOD, f"warpvx: {text}")

    # ---------------------------------------------------------------- processing thread

    def _next(self):
        """The next queued (header, frame), or None once closed; warns while the camera is silent."""
        silent = False
        while True:
            item = self._queue.get(self.watchdog)
            if item is FrameQueue.CLOSED:
                return None
            if item is not None:
                if silent:
                    self.rospy.loginfo(f"warpvx: {self._camera_topic}: frames again")
                return item
            if not silent:
                self.rospy.logwarn(f"warpvx: {self._camera_topic}: no frame for {self.watchdog:g} s "
                                   f"(publisher gone?); waiting")
                silent = True

    def _frames(self, first):
        """Frames for one run of the graph's stream: ``first``, then those already queued that
        the graph accepts. It ends when the queue is empty, so the stream hands back the frames
        in flight at once instead of holding them until the camera's next frame; pipelining
        (``depth``) works whenever frames wait, which is when throughput matters."""
        from ..graph.verify import check_input

        item = first
        while item is not None and item is not FrameQueue.CLOSED:
            header, frame = item
            graph_frame = {k: v for k, v in frame.items() if k in self.graph.inputs}
            try:
                for name, value in graph_frame.items():
                    check_input(self.graph.inputs[name], value)
            except WarpvxError as exc:
                self._reject(f"{self._camera_topic}: frame rejected: {exc} (did the image size "
                             f"change mid-stream?)")
            else:
                self._in_flight.append((header, frame))
                yield graph_frame
            item = self._queue.get(0)

    def _run(self):
        history = deque(maxlen=self.lag + 1)
        while (first := self._next()) is not None:
            try:
                if self.graph is None:
                    self.graph = self._make(first[1])
                for outputs in self.graph.stream(self._frames(first), depth=self.depth):
                    self._emit(outputs, *self._in_flight.popleft(), history)
            except WarpvxError as exc:
                self._count("errors", len(self._in_flight) or 1)
                self._in_flight.clear()
                self.rospy.logerr(f"warpvx: graph {getattr(self.graph, 'name', '?')!r}: {exc}; "
                                  f"going on with the next frame")
            except Exception as exc:  # noqa: BLE001 - a post/publish bug must not kill the node silently
                self.rospy.logfatal(f"warpvx: client stopped: {type(exc).__name__}: {exc}")
                raise

    def _emit(self, outputs, header, inputs, history):
        self._count("processed")
        history.append(header)
        if self._post is not None:
            outputs = {**outputs, **self._post(outputs, inputs, header)}
        if len(history) > self.lag:
            for name, pub in self._pubs.items():
                message = self._outputs[name].convert(outputs[name], history[0])
                if message is not None:
                    pub.publish(message)
            self._count("published")
        if self._dropped_pub is not None:
            self._dropped_pub.publish(self.stats.dropped)

    # ---------------------------------------------------------------- lifetime

    def close(self, timeout: float = 10.0):
        """Stop: unsubscribe, let the frames in flight finish (up to ``timeout`` s), log the
        summary (:meth:`FrameStats.summary`) and unregister the publishers. Idempotent."""
        if self._queue is None:
            return
        for sub in self._subs:
            sub.unregister()
        self._queue.close()
        self._thread.join(timeout)
        if self._thread.is_alive():
            self.rospy.logwarn(f"warpvx: the processing thread did not stop within {timeout:g} s")
        self.rospy.loginfo(f"warpvx: {self._camera_topic}: {self.stats.summary()}")
        for pub in [*self._pubs.values(), self._dropped_pub]:
            if pub is not None:
                pub.unregister()
        self._queue = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

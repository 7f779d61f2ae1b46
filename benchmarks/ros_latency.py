"""ROS message round trip vs the graph's own time (issue 15): 640x480 and 1280x720, mono8 and
bgr8, through a real roscore on a free loopback port.

Per case: a GraphClient runs a one-node graph (Gaussian blur 5x5) on frames published on a
topic; the round trip is publish -> client -> graph -> publish -> back to this process
(median of sequential frames); the graph's own time is the median of ``graph.process`` on the
same frames; throughput is frames received per second while publishing back to back.

    PYTHONPATH=. python benchmarks/ros_latency.py [--frames 60] [--backend cpu]

Writes a Markdown table to stdout and ``$OUT/ros_latency.md`` when ``OUT`` is set.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time

import cv2
import numpy as np

SIZES = [(640, 480), (1280, 720)]
ENCODINGS = ["mono8", "bgr8"]


def start_roscore():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    os.environ.update(ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_HOSTNAME="127.0.0.1",
                      ROS_HOME=tempfile.mkdtemp(prefix="ros_home"))
    proc = subprocess.Popen(["roscore", "-p", str(port)], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    import rosgraph

    while not rosgraph.is_master_online():
        time.sleep(0.1)
    return proc


def blur_graph(shape, backend):
    import warpvx

    g = warpvx.Graph("bench")
    frame = g.input("frame", shape=shape, dtype=np.uint8)
    g.output("out", g.gaussian_blur(frame, ksize=5, sigma=1.5, name="blur",
                                    target=None if backend == "cpu" else "gpu"))
    g.schedule("best", gpu=False if backend == "cpu" else backend)
    return g


def run_case(rospy, size, encoding, frames, backend, case):
    from sensor_msgs.msg import Image

    from warpvx.ros import GraphClient, array_to_image, image_input, image_output

    w, h = size
    photo = cv2.resize(cv2.imread(os.path.join("warpvx", "data", "astronaut_448.png")), (w, h))
    image = cv2.cvtColor(photo, cv2.COLOR_BGR2GRAY) if encoding == "mono8" else photo
    graph = blur_graph(image.shape, backend)
    for _ in range(5):
        graph.process({"frame": image})
    own = []
    for _ in range(frames):
        t = time.perf_counter()
        graph.process({"frame": image})
        own.append(time.perf_counter() - t)
    topic = f"/bench{case}"
    client = GraphClient(graph, {"frame": image_input(topic + "/in", encoding)},
                         {"out": image_output(topic + "/out", encoding)}, queue_size=frames,
                         publish_queue=frames, dropped_topic=None)
    got, cond = [], threading.Condition()

    def on(msg):
        with cond:
            got.append(time.perf_counter())
            cond.notify_all()

    sub = rospy.Subscriber(topic + "/out", Image, on, queue_size=None, buff_size=1 << 26)
    pub = rospy.Publisher(topic + "/in", Image, queue_size=frames)
    while pub.get_num_connections() == 0 or sub.get_num_connections() == 0:
        time.sleep(0.02)
    msg = array_to_image(image, encoding)
    trips = []
    for i in range(frames + 5):  # sequential: one frame at a time
        with cond:
            t = time.perf_counter()
            pub.publish(msg)
            cond.wait_for(lambda: len(got) > i, 10)
        if i >= 5:
            trips.append(got[-1] - t)
    start, base = time.perf_counter(), len(got)
    for _ in range(frames):  # back to back
        pub.publish(msg)
    with cond:
        cond.wait_for(lambda: len(got) >= base + frames, 30)
    rate = (len(got) - base) / (got[-1] - start)
    client.close()
    sub.unregister()
    pub.unregister()
    return np.median(trips) * 1e3, np.median(own) * 1e3, rate


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--backend", default="cpu")
    args = parser.parse_args()
    from warpvx.ros import import_rospy

    rospy = import_rospy()
    if shutil.which("roscore") is None:
        raise SystemExit("roscore is not installed (apt-get install ros-core)")
    core = start_roscore()
    try:
        rospy.init_node("warpvx_bench", anonymous=True, disable_signals=True)
        lines = [f"backend {args.backend}, {args.frames} frames per case, {os.cpu_count()} cores", "",
                 "| size | encoding | round trip (ms, median) | graph alone (ms) | ROS overhead (ms) | throughput (FPS) |",
                 "| --- | --- | --- | --- | --- | --- |"]
        for case, (size, enc) in enumerate([(s, e) for s in SIZES for e in ENCODINGS]):
            trip, own, rate = run_case(rospy, size, enc, args.frames, args.backend, case)
            lines.append(f"| {size[0]}x{size[1]} | {enc} | {trip:.2f} | {own:.2f} | {trip - own:.2f} | {rate:.0f} |")
            print(lines[-1], flush=True)
        text = "\n".join(lines) + "\n"
        print(text)
        if os.environ.get("OUT"):
            with open(os.path.join(os.environ["OUT"], "ros_latency.md"), "w") as f:
                f.write(text)
        rospy.signal_shutdown("done")
    finally:
        core.send_signal(signal.SIGINT)
        core.wait(20)


if __name__ == "__main__":
    main()

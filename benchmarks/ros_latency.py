"""ROS 1 round trip and throughput of a graph node vs the graph's own time (issue 15):
640x480 and 1280x720, mono8 and bgr8, through a real master on a free loopback port.

Per case a GraphClient (the client model) runs a one-node graph (Gaussian blur 5x5, sigma 1.5;
on ``--backend`` cuda or warp-cpu the node runs there, the graph uploading the frame and
downloading the result) on frames published on a topic, and publishes the result:

* round trip: publish -> client -> graph -> publish -> received back here, one frame at a time
  (median and 90th percentile of ``--frames`` frames, after 5 untimed);
* graph alone: ``graph.process`` on the same frame in this process (median);
* ROS serialisation: what one hop costs in this process, the array -> message conversion
  (one copy), genpy's serialise, the bytes, genpy's deserialise and the message -> array view;
  a round trip has two hops (frame in, result out);
* the rest (round trip - graph - 2 hops): sockets, rospy's and the client's threads;
* throughput: frames received back per second while ``--frames`` frames are published back to
  back (no frame dropped: the queues hold them all).

Usage (from the repository root)::

    PYTHONPATH=. python3 benchmarks/ros_latency.py [--backend cpu] [--frames 60] [--out DIR]

On a machine without ROS (the GPU machine): build the bundle where the Debian ROS packages
are (``python3 tools/ros_bundle.py``), carry ``build/rosbundle/`` along, then::

    source build/rosbundle/env.sh && PYTHONPATH=. python3 benchmarks/ros_latency.py --backend cuda --out $OUT/ros

The master is whatever ``roscore`` the PATH holds (the bundle's starts rosmaster alone).
Writes ``ros_latency.md`` (the regenerate command at its top) and ``ros_latency.json`` into
``--out`` (default: ``$OUT`` when set, else a new ``./warpvx-results/ros_latency-<time>/``).
About 20 s on a 2-core machine with the default 60 frames.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time

import cv2
import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

from warpvx.bench.inputs import load_photo_with_source  # noqa: E402
from warpvx.bench.report import machine_info  # noqa: E402
from warpvx.cli import fresh_results_dir, positive_int  # noqa: E402

SIZES = [(640, 480), (1280, 720)]
ENCODINGS = ["mono8", "bgr8"]
WARMUP = 5
#: Seconds any wait may take (the master starting, a frame coming back) before the run fails.
WAIT = 30.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_master(home: str):
    """``roscore -p PORT`` on a free loopback port (its own session), once it answers; this
    process' environment points ROS at it. Returns (process, roscore's path)."""
    roscore = shutil.which("roscore")
    if roscore is None:
        raise SystemExit("roscore is not on PATH: apt-get install ros-core, or source a bundle "
                         "made by tools/ros_bundle.py (build/rosbundle/env.sh)")
    port = free_port()
    os.environ.update(ROS_MASTER_URI=f"http://127.0.0.1:{port}", ROS_HOSTNAME="127.0.0.1",
                      ROS_HOME=home)
    os.environ.pop("ROS_IP", None)
    log = open(os.path.join(home, "roscore.log"), "w")
    proc = subprocess.Popen([roscore, "-p", str(port)], stdout=log, stderr=subprocess.STDOUT,
                            start_new_session=True)
    log.close()
    import rosgraph

    deadline = time.monotonic() + WAIT
    try:
        while not rosgraph.is_master_online():
            if proc.poll() is not None or time.monotonic() > deadline:
                with open(os.path.join(home, "roscore.log")) as f:
                    raise SystemExit(f"{roscore} did not start on port {port}:\n{f.read()[-2000:]}")
            time.sleep(0.1)
    except BaseException:  # includes SIGTERM's SystemExit: leave no master behind
        stop_master(proc)
        raise
    return proc, roscore


def stop_master(proc):
    """SIGINT the master's process group (roscore stops its children), SIGKILL if it hangs."""
    for sig in (signal.SIGINT, signal.SIGKILL):
        if proc.poll() is not None:
            return
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            pass


def blur_graph(shape, backend):
    import warpvx

    g = warpvx.Graph("bench")
    frame = g.input("frame", shape=shape, dtype=np.uint8)
    g.output("out", g.gaussian_blur(frame, ksize=5, sigma=1.5, name="blur",
                                    target=None if backend == "cpu" else "gpu"))
    g.schedule("best", gpu=False if backend == "cpu" else backend)
    return g


def median_ms(samples) -> float:
    return float(np.median(samples) * 1e3)


def graph_alone_ms(graph, image, frames) -> float:
    """Median ``graph.process`` time (ms) of ``frames`` calls after :data:`WARMUP`."""
    for _ in range(WARMUP):
        graph.process({"frame": image})
    times = []
    for _ in range(frames):
        t = time.perf_counter()
        graph.process({"frame": image})
        times.append(time.perf_counter() - t)
    return median_ms(times)


def hop_ms(image, encoding, frames) -> dict:
    """Median ms of one hop's ROS work in this process: array -> message (``to_msg``),
    serialise, deserialise and message -> array (``to_array``), as rospy and warpvx.ros do
    them (the publisher serialises into a BytesIO and sends its bytes; the subscriber
    deserialises from the bytes it read)."""
    from sensor_msgs.msg import Image

    from warpvx.ros import array_to_image, image_to_array

    parts = {"to_msg": [], "serialise": [], "deserialise": [], "to_array": []}
    for i in range(WARMUP + frames):
        t0 = time.perf_counter()
        msg = array_to_image(image, encoding)
        t1 = time.perf_counter()
        buff = io.BytesIO()
        msg.serialize(buff)
        data = buff.getvalue()
        t2 = time.perf_counter()
        back = Image().deserialize(data)
        t3 = time.perf_counter()
        image_to_array(back, encoding)
        t4 = time.perf_counter()
        if i >= WARMUP:
            for key, dt in zip(parts, (t1 - t0, t2 - t1, t3 - t2, t4 - t3)):
                parts[key].append(dt)
    return {key: median_ms(v) for key, v in parts.items()}


class Inbox:
    """Arrival times of the messages of one topic; :meth:`wait` blocks until ``n`` came."""

    def __init__(self, rospy, topic):
        from sensor_msgs.msg import Image

        self.times, self._cond = [], threading.Condition()
        self.sub = rospy.Subscriber(topic, Image, self._on, queue_size=None, buff_size=1 << 26)

    def _on(self, _msg):
        with self._cond:
            self.times.append(time.perf_counter())
            self._cond.notify_all()

    def wait(self, n, what):
        with self._cond:
            if not self._cond.wait_for(lambda: len(self.times) >= n, WAIT):
                raise SystemExit(f"{self.sub.resolved_name}: {len(self.times)} of {n} messages "
                                 f"within {WAIT:g} s ({what})")


def run_case(rospy, image, encoding, frames, backend, case) -> dict:
    """One size/encoding: the round trip, the graph alone, one hop's ROS work, throughput."""
    from sensor_msgs.msg import Image

    from warpvx.ros import GraphClient, array_to_image, image_input, image_output

    graph = blur_graph(image.shape, backend)
    own = graph_alone_ms(graph, image, frames)
    hop = hop_ms(image, encoding, frames)
    topic = f"/bench{case}"
    client = GraphClient(graph, {"frame": image_input(topic + "/in", encoding)},
                         {"out": image_output(topic + "/out", encoding)}, queue_size=frames,
                         publish_queue=frames, dropped_topic=None)
    inbox = Inbox(rospy, topic + "/out")
    pub = rospy.Publisher(topic + "/in", Image, queue_size=frames)
    deadline = time.monotonic() + WAIT
    while pub.get_num_connections() == 0 or inbox.sub.get_num_connections() == 0:
        if time.monotonic() > deadline:
            raise SystemExit(f"{topic}: the client did not connect within {WAIT:g} s")
        time.sleep(0.02)
    msg = array_to_image(image, encoding)
    trips = []
    for i in range(WARMUP + frames):  # sequential: one frame in flight
        t = time.perf_counter()
        pub.publish(msg)
        inbox.wait(i + 1, "round trip")
        if i >= WARMUP:
            trips.append(inbox.times[i] - t)
    base = len(inbox.times)
    start = time.perf_counter()
    for _ in range(frames):  # back to back
        pub.publish(msg)
    inbox.wait(base + frames, "throughput")
    fps = frames / (inbox.times[-1] - start)
    stats = client.stats
    client.close()
    inbox.sub.unregister()
    pub.unregister()
    trip = median_ms(trips)
    ros = 2 * sum(hop.values())
    return {"size": f"{image.shape[1]}x{image.shape[0]}", "encoding": encoding,
            "mb_per_msg": round(len(msg.data) / 1e6, 3),
            "round_trip_ms": round(trip, 3), "round_trip_p90_ms": round(float(np.percentile(trips, 90)) * 1e3, 3),
            "graph_ms": round(own, 3), "hop_ms": {k: round(v, 3) for k, v in hop.items()},
            "ros_serialisation_ms": round(ros, 3), "rest_ms": round(trip - own - ros, 3),
            "throughput_fps": round(fps, 1), "throughput_mb_s": round(fps * len(msg.data) / 1e6, 1),
            "client": {"received": stats.received, "processed": stats.processed,
                       "dropped": stats.dropped, "rejected": stats.rejected}}


HEADER = ("| size | encoding | MB/msg | round trip ms (median / p90) | graph alone ms | "
          "ROS serialisation ms (2 hops) | rest ms (sockets, threads) | throughput FPS (MB/s) |")


def markdown(report) -> str:
    m, ros, load = report["machine"], report["ros"], report["load_average_1min"]
    gpu = ", ".join(g["name"] for g in m["gpus"]) or "no GPU"
    lines = [f"Regenerate: `{report['command']}`", "",
             f"# ROS 1 round trip of a graph node: backend {report['backend']}", "",
             f"{m['cpu_model']} ({m['cpu_cores']} cores), {gpu}; Python {m['python']}, "
             f"warpvx {m['versions']['warpvx']}, warp {m['versions'].get('warp', '-')}, "
             f"OpenCV {m['versions']['opencv']}; rospy from `{ros['rospy']}`, master "
             f"`{ros['roscore']}`; {report['frames']} frames per case; {report['date']}; load "
             f"average (1 min) at start / end {load[0]:.1f} / {load[1]:.1f} (on {m['cpu_cores']} "
             f"cores: above that, other processes shared them).", "",
             HEADER, "| --- " * 8 + "|"]
    for r in report["rows"]:
        lines.append(f"| {r['size']} | {r['encoding']} | {r['mb_per_msg']:.2f} | "
                     f"{r['round_trip_ms']:.2f} / {r['round_trip_p90_ms']:.2f} | {r['graph_ms']:.2f} | "
                     f"{r['ros_serialisation_ms']:.2f} | {r['rest_ms']:.2f} | "
                     f"{r['throughput_fps']:.0f} ({r['throughput_mb_s']:.0f}) |")
    lines += ["", "One hop (ms, median): " + "; ".join(
        f"{r['size']} {r['encoding']}: " + ", ".join(f"{k} {v:.3f}" for k, v in r["hop_ms"].items())
        for r in report["rows"]), "",
        "Round trip: publish -> GraphClient -> graph -> publish -> back, one frame at a time. "
        "Graph alone: `graph.process` in this process (with the upload/download on a GPU "
        "backend). ROS serialisation: array -> message, genpy serialise, deserialise, "
        "message -> array, measured in this process, times the two hops of a round trip. "
        "Rest: round trip - graph - serialisation (sockets, rospy's and the client's threads). "
        "Throughput: frames back per second with frames published back to back."]
    return "\n".join(lines) + "\n"


def command(argv) -> str:
    """The command that regenerates this run (with the bundle's env.sh when ROS came from one)."""
    bundle = os.environ.get("WARPVX_ROS_PYTHONPATH")
    prefix = (f"source {os.path.relpath(os.path.dirname(bundle.rstrip(os.sep)))}/env.sh && "
              if bundle else "")
    return prefix + "PYTHONPATH=. python3 benchmarks/ros_latency.py " + " ".join(argv)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--frames", type=positive_int, default=60,
                        help="timed frames per case (round trip, graph alone, throughput)")
    parser.add_argument("--backend", default="cpu", choices=["cpu", "warp-cpu", "cuda"],
                        help="where the graph's blur node runs")
    parser.add_argument("--out", default=os.environ.get("OUT"),
                        help="results folder (default $OUT, else ./warpvx-results/ros_latency-<time>/)")
    args = parser.parse_args(argv)
    from warpvx.ros import import_rospy

    rospy = import_rospy()
    out = args.out or str(fresh_results_dir("ros_latency"))
    os.makedirs(out, exist_ok=True)
    photo, source = load_photo_with_source()
    load_start = os.getloadavg()[0]
    home = tempfile.mkdtemp(prefix="ros_latency_home")
    # `timeout` sends SIGTERM: exit through the handlers that stop the master
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("ros_latency: terminated"))
    core, roscore = start_master(home)
    print(f"rospy {rospy.__file__}, master {roscore} at {os.environ['ROS_MASTER_URI']}, "
          f"backend {args.backend}", flush=True)
    rows = []
    try:
        rospy.init_node("warpvx_bench", anonymous=True, disable_signals=True)
        for case, ((w, h), enc) in enumerate((s, e) for s in SIZES for e in ENCODINGS):
            image = cv2.resize(photo, (w, h), interpolation=cv2.INTER_AREA)
            image = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if enc == "mono8" else image
            rows.append(run_case(rospy, image, enc, args.frames, args.backend, case))
            r = rows[-1]
            print(f"{r['size']} {enc}: round trip {r['round_trip_ms']:.2f} ms, graph {r['graph_ms']:.2f}, "
                  f"serialisation {r['ros_serialisation_ms']:.2f}, {r['throughput_fps']:.0f} FPS", flush=True)
        rospy.signal_shutdown("done")
    finally:
        stop_master(core)
        shutil.rmtree(home, ignore_errors=True)
    report = {"command": command(argv), "backend": args.backend, "frames": args.frames,
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "photo": source,
              "machine": machine_info(), "load_average_1min": [load_start, os.getloadavg()[0]],
              "ros": {"rospy": os.path.dirname(rospy.__file__), "roscore": roscore,
                      "bundle": os.environ.get("WARPVX_ROS_PYTHONPATH")},
              "rows": rows}
    with open(os.path.join(out, "ros_latency.json"), "w") as f:
        json.dump(report, f, indent=1)
    text = markdown(report)
    with open(os.path.join(out, "ros_latency.md"), "w") as f:
        f.write(text)
    print(text + f"\nwrote {out}/ros_latency.md and .json", flush=True)


if __name__ == "__main__":
    main()

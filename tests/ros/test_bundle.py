"""tools/ros_bundle.py: ROS 1's Python side packed from the Debian packages runs a graph node
without them (the GPU machine has no ROS): a fresh interpreter that cannot see
``/usr/lib/python3/dist-packages`` imports rospy from the bundle through
``WARPVX_ROS_PYTHONPATH``, talks to the bundle's own master, and gets back OpenCV's blur of a
real frame. Skipped where the Debian ROS packages are not installed (the bundle is made from
them)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import cv2
import numpy as np
import pytest

from tests.isolated import ROOT as REPO
from tests.ros.conftest import WAIT, _free_port, kill_roscore, start_roscore


@pytest.fixture(scope="module")
def bundle(tmp_path_factory):
    """A bundle built into a temporary folder (the build's own -I -S import check passed)."""
    if shutil.which("dpkg-query") is None or subprocess.run(
            ["dpkg-query", "-W", "python3-rospy"], capture_output=True).returncode:
        pytest.skip("the Debian ROS 1 packages (python3-rospy, ...) are not installed")
    out = tmp_path_factory.mktemp("bundle") / "rosbundle"
    built = subprocess.run([sys.executable, str(REPO / "tools" / "ros_bundle.py"), "--out", str(out)],
                           capture_output=True, text=True, timeout=120)
    assert built.returncode == 0, built.stdout + built.stderr
    assert "bundle OK" in built.stdout
    return out


def test_bundle_holds_no_c_extension(bundle):
    built_for = [str(p) for p in bundle.rglob("*") if p.suffix in (".so", ".pyd")]
    assert built_for == []
    assert (bundle / "python" / "rospy").is_dir() and (bundle / "python" / "netifaces.py").is_file()
    assert os.access(bundle / "bin" / "roscore", os.X_OK)


def test_netifaces_stand_in_lists_what_the_c_module_lists(bundle):
    real = subprocess.run(["/usr/bin/python3", "-c", "import netifaces as n; print(sorted("
                           "a['addr'] for i in n.interfaces() for a in n.ifaddresses(i).get(n.AF_INET, [])))"],
                          capture_output=True, text=True)
    if real.returncode:
        pytest.skip(f"the C netifaces does not import: {real.stderr[-300:]}")
    stand_in = subprocess.run([sys.executable, "-I", "-S", "-c", "import sys; sys.path.append(sys.argv[1]); "
                               "import netifaces as n; print(sorted(a['addr'] for i in n.interfaces() "
                               "for a in n.ifaddresses(i).get(n.AF_INET, [])))", str(bundle / "python")],
                              capture_output=True, text=True, check=True)
    assert stand_in.stdout == real.stdout


NODE = """
import os, sys, threading
sys.path[:] = [p for p in sys.path if "dist-packages" not in p]  # no system ROS
import numpy as np
import warpvx
from warpvx.ros import GraphClient, array_to_image, image_input, image_output, image_to_array, import_rospy

rospy = import_rospy()
assert rospy.__file__.startswith(os.environ["WARPVX_ROS_PYTHONPATH"]), rospy.__file__
from sensor_msgs.msg import Image

frame = np.load(sys.argv[1])
g = warpvx.Graph("bundle")
g.output("out", g.gaussian_blur(g.input("frame", shape=frame.shape, dtype=np.uint8), ksize=5,
                                sigma=1.5, name="blur"))
rospy.init_node("bundle_test", anonymous=True, disable_signals=True)
client = GraphClient(g, {"frame": image_input("/bundle/in", "bgr8")},
                     {"out": image_output("/bundle/out", "bgr8")}, dropped_topic=None)
got = threading.Event()
back = []
sub = rospy.Subscriber("/bundle/out", Image, lambda m: (back.append(image_to_array(m)), got.set()))
pub = rospy.Publisher("/bundle/in", Image, queue_size=1)
deadline = float(sys.argv[3])
while pub.get_num_connections() == 0 or sub.get_num_connections() == 0:
    rospy.sleep(0.02)
pub.publish(array_to_image(frame, "bgr8"))
assert got.wait(deadline), "no result within the deadline"
client.close()
np.save(sys.argv[2], back[0])
outside = sorted({m.__file__ for m in list(sys.modules.values())
                  if "dist-packages" in (getattr(m, "__file__", None) or "")})
assert not outside, outside
rospy.signal_shutdown("done")
"""


def test_graph_node_runs_on_the_bundle_alone(bundle, bikes, tmp_path, monkeypatch):
    """The bundle's roscore (rosmaster alone) and rospy: a real frame through a GraphClient
    comes back as cv2.GaussianBlur of it."""
    from warpvx.ros import import_rospy

    import_rospy()  # this process' rosgraph (system or bundle) waits for the master
    import rosgraph

    env = {"WARPVX_ROS_PYTHONPATH": str(bundle / "python"), "ROS_ETC_DIR": str(bundle / "etc" / "ros"),
           "PATH": os.pathsep.join([str(bundle / "bin"), os.path.dirname(sys.executable), os.environ["PATH"]]),
           "ROS_HOSTNAME": "127.0.0.1", "ROS_HOME": str(tmp_path), "PYTHONPATH": str(REPO)}
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    port = _free_port()
    monkeypatch.setenv("ROS_MASTER_URI", f"http://127.0.0.1:{port}")
    monkeypatch.delenv("ROS_IP", raising=False)
    core = start_roscore(port, tmp_path / "roscore.log")
    try:
        pid = rosgraph.Master("/bundle_test_check", master_uri=os.environ["ROS_MASTER_URI"]).getPid()
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            assert str(bundle / "bin" / "rosmaster").encode() in f.read()
        frame = bikes[0]
        np.save(tmp_path / "frame.npy", frame)
        node = subprocess.run([sys.executable, "-c", NODE, str(tmp_path / "frame.npy"),
                               str(tmp_path / "back.npy"), str(WAIT)], cwd=REPO,
                              capture_output=True, text=True, timeout=3 * WAIT)
        assert node.returncode == 0, node.stdout[-2000:] + node.stderr[-3000:]
    finally:
        kill_roscore(core)
    np.testing.assert_array_equal(np.load(tmp_path / "back.npy"), cv2.GaussianBlur(frame, (5, 5), 1.5))

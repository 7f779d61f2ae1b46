"""Pack ROS 1's Python side from this machine's Debian packages into a directory that runs on a
machine without ROS (issue 15: the GPU machine has Python 3.12, no ROS, no package registry).

    python3 tools/ros_bundle.py [--out build/rosbundle]   # on a machine with the Debian ROS
    source build/rosbundle/env.sh                          # on the machine without it

What the directory holds (~10 MB; carry it whole, any path):

- ``python/``: the pure-Python files ``dpkg -L`` lists under ``/usr/lib/python3/dist-packages``
  for :data:`PACKAGES` (rospy, rosgraph, rosmaster, roslib, rospkg, catkin_pkg, genpy, genmsg,
  the message packages, and their dependencies yaml, defusedxml, pyparsing, ...). C extensions
  are left out, since they are built for this machine's Python and would not load on another:
  each must have a pure-Python fallback, listed in :data:`C_FALLBACKS` (an unknown one stops
  the build). ``netifaces`` has none, so a two-call stand-in is written (:data:`NETIFACES`).
- ``bin/rosmaster`` (ROS 1's master, pure Python) and ``bin/roscore``: the master alone, as
  ``roscore -p PORT`` starts it, without ``rosout`` (C++; not carried). Nodes still log to the
  ``/rosout`` topic; nothing aggregates it.
- ``etc/ros/python_logging.conf`` (rospy's and rosmaster's logging configuration).
- ``env.sh``: puts ``bin`` on ``PATH``, points ``ROS_ETC_DIR`` there and sets
  ``WARPVX_ROS_PYTHONPATH`` to ``python/``, which :mod:`warpvx.ros._env` *appends* to
  ``sys.path`` at the first use of ROS, so the interpreter's own packages (NumPy, a newer
  PyYAML) keep precedence. ``PYTHONPATH`` is left alone.

The build ends with a check: a fresh interpreter (``--python``, default this one; any version,
e.g. 3.12 to check the bundle for the GPU machine) started with ``-I -S`` (the standard library
only) imports every packed module from the bundle and compiles every packed file. Standard
library only.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import textwrap

DIST = "/usr/lib/python3/dist-packages"

#: Debian packages whose Python files are packed: what rospy, rosmaster and the message
#: modules warpvx.ros uses import, found by importing them and listing ``sys.modules``.
PACKAGES = [
    "python3-rospy", "python3-rosgraph", "python3-rosmaster", "python3-roslib", "python3-rospkg",
    "python3-catkin-pkg", "python3-catkin", "python3-genpy", "python3-genmsg",
    "python3-std-msgs", "python3-sensor-msgs", "python3-geometry-msgs", "python3-nav-msgs",
    "python3-rosgraph-msgs", "python3-roscpp-msg", "python3-actionlib-msgs",
    "python3-yaml", "python3-defusedxml", "python3-pyparsing", "python3-distro",
    "python3-dateutil", "python3-six", "python3-netifaces",
]

#: C extensions left out, and what runs instead.
C_FALLBACKS = {
    "yaml/_yaml": "PyYAML's pure-Python loader and dumper (yaml.__with_libyaml__ is False)",
    "netifaces": "python/netifaces.py, written here (interfaces and IPv4 ifaddresses)",
}

#: Module names the check imports from the bundle alone.
MODULES = [
    "rospy", "rosgraph", "rosgraph.network", "rosmaster.main", "roslib", "rospkg", "catkin_pkg",
    "genpy.dynamic", "genmsg.gentools", "genmsg.msg_loader", "yaml", "netifaces",
    "std_msgs.msg", "sensor_msgs.msg", "geometry_msgs.msg", "nav_msgs.msg", "rosgraph_msgs.msg",
]

#: The stand-in for netifaces (a C module): the two calls rosgraph.network makes to list this
#: host's addresses when neither ROS_IP nor ROS_HOSTNAME is set.
NETIFACES = '''\
"""netifaces' ``interfaces`` and ``ifaddresses`` (IPv4 only) in pure Python, for
interpreters without the C module; written by warpvx's tools/ros_bundle.py."""

import fcntl
import socket
import struct

AF_INET = socket.AF_INET
_SIOCGIFADDR = 0x8915  # Linux ioctl: an interface's IPv4 address


def interfaces():
    """Names of this host's network interfaces."""
    return [name for _, name in socket.if_nameindex()]


def ifaddresses(iface):
    """``{AF_INET: [{"addr": "a.b.c.d"}]}``, or ``{}`` when ``iface`` has no IPv4 address."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            ifreq = fcntl.ioctl(s.fileno(), _SIOCGIFADDR, struct.pack("256s", iface.encode()[:15]))
        except OSError:
            return {}
    return {AF_INET: [{"addr": socket.inet_ntoa(ifreq[20:24])}]}
'''

ROSMASTER = '''\
#!/usr/bin/env python3
"""ROS 1's master (rosmaster) from this bundle."""
import os
import sys

sys.path.append(os.path.join(os.path.dirname(os.path.dirname(os.path.realpath(__file__))), "python"))
import rosmaster

rosmaster.rosmaster_main()
'''

ROSCORE = '''\
#!/bin/sh
# roscore without rosout (C++, not in this bundle): the master alone, as `roscore -p PORT` starts it.
exec "$(dirname "$0")/rosmaster" --core "$@"
'''

ENV_SH = '''\
# Source me (bash or zsh): ROS 1's Python side from this bundle, for warpvx.ros and rosmaster/roscore.
# Built by warpvx's tools/ros_bundle.py from Debian packages: {packages}.
ROSBUNDLE="$(cd "$(dirname "${{BASH_SOURCE[0]:-$0}}")" && pwd)"
chmod +x "$ROSBUNDLE"/bin/* 2>/dev/null || true  # a copy that lost the mode bits
export WARPVX_ROS_PYTHONPATH="$ROSBUNDLE/python"
export ROS_ETC_DIR="$ROSBUNDLE/etc/ros"
export ROS_VERSION=1 ROS_PYTHON_VERSION=3 ROS_DISTRO="${{ROS_DISTRO:-debian}}"
export PATH="$ROSBUNDLE/bin:$PATH"
'''

#: Run by the check's fresh interpreter: import each module from the bundle alone, compile
#: every packed file, and compare the netifaces stand-in with the standard library.
CHECK = '''\
import os, socket, sys
bundle = sys.argv[1]
sys.path.append(bundle)
for name in sys.argv[2:]:
    __import__(name)
outside = sorted({m.__file__ for m in list(sys.modules.values())
                  if getattr(m, "__file__", None) and "dist-packages" in m.__file__})
assert not outside, f"imported from outside the bundle: {outside[:5]}"
import yaml, netifaces
assert not yaml.__with_libyaml__ and netifaces.__file__.startswith(bundle)
for root, _, files in os.walk(bundle):
    for f in files:
        if f.endswith(".py"):
            path = os.path.join(root, f)
            with open(path, "rb") as src:
                compile(src.read(), path, "exec")
lo = netifaces.ifaddresses("lo")[netifaces.AF_INET][0]["addr"]
assert lo.startswith("127."), lo
import rosgraph.network
print(f"bundle OK on Python {sys.version.split()[0]}: {len(sys.argv) - 2} modules, "
      f"local addresses {rosgraph.network.get_local_addresses()}")
'''


def package_files(package: str) -> list[str]:
    """Files ``package`` installed under :data:`DIST` (not directories, not byte code)."""
    listed = subprocess.run(["dpkg", "-L", package], capture_output=True, text=True)
    if listed.returncode:
        raise SystemExit(f"ros_bundle: Debian package {package} is not installed "
                         f"({listed.stderr.strip()}); apt-get install {package}")
    return [p for p in listed.stdout.split()
            if p.startswith(DIST + "/") and os.path.isfile(p) and "/__pycache__/" not in p
            and ".egg-info" not in p and ".dist-info" not in p]


def c_fallback(relative: str) -> str:
    """What replaces the C extension at ``relative`` (a path under dist-packages); stops the
    build for one without a known pure-Python fallback."""
    for prefix, instead in C_FALLBACKS.items():
        if relative.startswith(prefix + ".") or relative.startswith(prefix + "/"):
            return instead
    raise SystemExit(f"ros_bundle: {relative} is a C extension with no known pure-Python "
                     f"fallback; it would not load on another Python version")


def write(path: str, text: str, mode: int = 0o644):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write(text)
    os.chmod(path, mode)


def build(out: str) -> list[str]:
    """Write the bundle into ``out`` (replaced if it exists); returns the C extensions left out
    with their fallbacks, one line each."""
    shutil.rmtree(out, ignore_errors=True)
    python = os.path.join(out, "python")
    skipped = []
    for package in PACKAGES:
        for src in package_files(package):
            relative = os.path.relpath(src, DIST)
            if src.endswith(".so"):
                skipped.append(f"{relative}: {c_fallback(relative)}")
                continue
            os.makedirs(os.path.join(python, os.path.dirname(relative)), exist_ok=True)
            shutil.copy2(src, os.path.join(python, relative))
    write(os.path.join(python, "netifaces.py"), NETIFACES)
    write(os.path.join(out, "bin", "rosmaster"), ROSMASTER, 0o755)
    write(os.path.join(out, "bin", "roscore"), ROSCORE, 0o755)
    os.makedirs(os.path.join(out, "etc", "ros"))
    shutil.copy2("/etc/ros/python_logging.conf", os.path.join(out, "etc", "ros"))
    write(os.path.join(out, "env.sh"), ENV_SH.format(packages=", ".join(PACKAGES)))
    return skipped


def check(out: str, interpreter: str):
    """Import :data:`MODULES` from the bundle alone in a fresh ``interpreter`` (isolated, no
    site-packages: the standard library and the bundle only; environment PATH and HOME),
    compile every packed file; SystemExit on failure."""
    python = os.path.abspath(os.path.join(out, "python"))
    env = {k: os.environ[k] for k in ("PATH", "HOME") if k in os.environ}
    done = subprocess.run([interpreter, "-I", "-S", "-B", "-c", CHECK, python, *MODULES], env=env,
                          capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"ros_bundle: the check with {interpreter} failed:\n{done.stderr[-3000:]}")
    print(done.stdout.strip())


def size_mb(path: str) -> float:
    return sum(os.path.getsize(os.path.join(root, f))
               for root, _, files in os.walk(path) for f in files) / 1e6


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--out", default=os.path.join("build", "rosbundle"),
                        help="directory to write (replaced)")
    parser.add_argument("--python", default=sys.executable,
                        help="interpreter of the check; must not see " + DIST)
    args = parser.parse_args()
    skipped = build(args.out)
    print(f"wrote {args.out} ({size_mb(args.out):.1f} MB) from {len(PACKAGES)} Debian packages")
    print("C extensions left out:\n" + textwrap.indent("\n".join(skipped), "  "))
    check(args.out, args.python)


if __name__ == "__main__":
    main()

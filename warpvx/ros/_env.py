"""The one place that finds ROS 1's Python packages (``rospy``, ``sensor_msgs``, ...).

Debian and Ubuntu install ROS 1 (``apt-get install python3-rospy ros-core python3-sensor-msgs
python3-geometry-msgs python3-nav-msgs python3-std-msgs``) into
``/usr/lib/python3/dist-packages``, which only the distribution's own ``/usr/bin/python3``
searches. Another interpreter of the same Python version (a pyenv build, a virtual environment
without ``--system-site-packages``) finds them once that folder is on ``sys.path``:
:func:`import_rospy` first tries a plain import (a ROS workspace that was sourced, a venv with
system site packages), and only when that fails *appends* the folder, so the interpreter's own
packages (NumPy, OpenCV) keep precedence over the distribution's. Nothing else in warpvx touches
``sys.path``; importing :mod:`warpvx.ros` does not either, the first use of ROS does.

``WARPVX_ROS_PYTHONPATH`` (folders separated by ``os.pathsep``) replaces that folder. It is how
a machine without ROS uses a bundle made by ``tools/ros_bundle.py`` on one with it (pure-Python
copies of those packages, any Python 3 version): ``source build/rosbundle/env.sh`` sets it to
the bundle's ``python/`` and puts the bundle's ``rosmaster``/``roscore`` on ``PATH``.
"""

from __future__ import annotations

import importlib
import os
import sys

from ..errors import UnsupportedError

#: Where the distribution's ROS 1 Python packages live (``WARPVX_ROS_PYTHONPATH`` overrides:
#: folders separated by ``os.pathsep``, e.g. a bundle's ``python/``).
DIST_PACKAGES = "/usr/lib/python3/dist-packages"

INSTALL_HINT = ("apt-get install python3-rospy ros-core python3-sensor-msgs python3-geometry-msgs "
                "python3-nav-msgs python3-std-msgs")


def _ros_paths() -> list[str]:
    env = os.environ.get("WARPVX_ROS_PYTHONPATH")
    return [p for p in env.split(os.pathsep) if p] if env else [DIST_PACKAGES]


def import_rospy():
    """``rospy``, importing it from the distribution's dist-packages when needed.

    Raises
    ------
    UnsupportedError
        ROS 1 is not installed for this interpreter's Python version (the message says what
        to install and what the import said).
    """
    try:
        return importlib.import_module("rospy")
    except ImportError:
        pass
    for path in _ros_paths():
        if os.path.isdir(path) and path not in sys.path:
            sys.path.append(path)
    try:
        return importlib.import_module("rospy")
    except ImportError as exc:
        raise UnsupportedError(
            f"ROS 1: rospy cannot be imported by {sys.executable} (Python "
            f"{sys.version_info.major}.{sys.version_info.minor}; searched {_ros_paths()}): {exc}; "
            f"install it with `{INSTALL_HINT}`, or source a bundle made by tools/ros_bundle.py "
            f"(its env.sh sets WARPVX_ROS_PYTHONPATH)") from exc


def msg(module: str, name: str):
    """A ROS message class, e.g. ``msg("sensor_msgs", "Image")`` (imports rospy first)."""
    import_rospy()
    try:
        return getattr(importlib.import_module(f"{module}.msg"), name)
    except (ImportError, AttributeError) as exc:
        raise UnsupportedError(f"ROS message {module}/{name} is not installed ({exc}); "
                               f"install python3-{module.replace('_', '-')}") from exc

"""Server model (thesis §4.6, Fig. 4.10): a ROS service runs the graph on demand.

No service type installable from the distribution carries an image both ways (``std_srvs``
has none; ``sensor_msgs/SetCameraInfo``, ``nav_msgs/GetMap`` carry other things), so warpvx
defines ``warpvx/ProcessImage``::

    sensor_msgs/Image image
    ---
    sensor_msgs/Image image

and builds its Python classes at first use with genpy (the code generator rospy's own
packages come from), so no catkin package needs building. It is a real ROS 1 service (TCPROS,
registered with the master, same MD5 as a ``ProcessImage.srv`` of that text compiled in a
package named ``warpvx``): other languages call it with that file in a package of that name.
"""

from __future__ import annotations

import functools

from ..errors import WarpvxError
from ._env import import_rospy, msg as _msg
from .convert import array_to_image, check_encoding, image_to_array

SERVICE_TYPE = "warpvx/ProcessImage"
REQUEST_TEXT = "sensor_msgs/Image image\n"
RESPONSE_TEXT = "sensor_msgs/Image image\n"


@functools.lru_cache(maxsize=None)
def process_image_service():
    """The ``warpvx/ProcessImage`` service class (with ``_request_class`` and
    ``_response_class``), generated once per process."""
    import_rospy()
    import genmsg.gentools
    import genmsg.msg_loader as loader
    import genpy.dynamic

    image = _msg("sensor_msgs", "Image")
    separator = "\n" + "=" * 80 + "\n"

    def message(text, name):  # genpy's "gendeps --cat" form: the message, then its dependencies
        return genpy.dynamic.generate_dynamic(
            name, text + separator + "MSG: sensor_msgs/Image\n" + image._full_text)[name]

    context = loader.MsgContext.create_default()
    image_text, _, header_text = image._full_text.partition(separator)
    loader.load_msg_from_string(context, header_text.partition("\n")[2], "std_msgs/Header")
    loader.load_msg_from_string(context, image_text, "sensor_msgs/Image")
    spec = loader.load_srv_from_string(context, REQUEST_TEXT + "---\n" + RESPONSE_TEXT, SERVICE_TYPE)
    return type("ProcessImage", (), {
        "_type": SERVICE_TYPE,
        "_md5sum": genmsg.gentools.compute_md5(context, spec),
        "_request_class": message(REQUEST_TEXT, SERVICE_TYPE + "Request"),
        "_response_class": message(RESPONSE_TEXT, SERVICE_TYPE + "Response"),
    })


class GraphServer:
    """Expose a graph as the ROS service ``name`` (``warpvx/ProcessImage``).

    Each request's image becomes input ``input`` (converted to ``encoding``) of one
    :meth:`~warpvx.Graph.process` call; output ``output`` is the response image, stamped with
    the request's header. A bad request (an unsupported encoding, a size the graph refuses, a
    node that raises) fails that call with the warpvx error's message (the caller's
    ``rospy.ServiceException``) and is logged; the server keeps serving.

    Parameters
    ----------
    graph : warpvx.Graph
    name : str
        Service name (remappable; ``~process`` is private to the node).
    input, output : str
        The graph's image input and output.
    encoding : str
        What the graph's input wants (mono8, bgr8, rgb8); the response has the output's
        natural encoding (mono8 for HxW, else this one).
    constants : dict, optional
        Other inputs of the graph, given with every request.
    """

    def __init__(self, graph, name: str = "~process", *, input: str = "image", output: str = "image",
                 encoding: str = "bgr8", constants=None):
        self.rospy = rospy = import_rospy()
        check_encoding(encoding)
        self.graph, self.input, self.output, self.encoding = graph, input, output, encoding
        self._constants = dict(constants or {})
        self.calls = self.failures = 0
        self._service = rospy.Service(name, process_image_service(), self._handle)

    def _handle(self, request):
        self.calls += 1
        try:
            image = image_to_array(request.image, self.encoding)
            result = self.graph.process({**self._constants, self.input: image})[self.output]
            encoding = self.encoding if result.ndim == 3 else "mono8"
            return {"image": array_to_image(result, encoding, request.image.header)}
        except WarpvxError as exc:
            self.failures += 1
            self.rospy.logerr(f"warpvx: service {self._service.resolved_name}: request failed: {exc}")
            raise self.rospy.ServiceException(f"warpvx: {exc}") from exc

    def close(self):
        """Unregister the service."""
        self._service.shutdown("closed")


def call_process_image(name: str, image, *, encoding: str | None = None, timeout: float = 10.0):
    """Call a ``warpvx/ProcessImage`` service ``name`` with uint8 ``image``; returns the
    response's pixels (uint8 HxW or HxWx3, in the response's encoding).

    Raises
    ------
    rospy.ROSException
        The service did not appear within ``timeout`` seconds.
    rospy.ServiceException
        The server failed the request (its message says why).
    """
    rospy = import_rospy()
    rospy.wait_for_service(name, timeout)
    proxy = rospy.ServiceProxy(name, process_image_service())
    try:
        return image_to_array(proxy(array_to_image(image, encoding)).image)
    finally:
        proxy.close()

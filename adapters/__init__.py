"""Adapters between the tracking service and the protocols ground stations already speak.

Each adapter is a client of the service (through :mod:`arcf.client`, the same SDK a station
uses), never part of it: the service knows nothing of MAVLink, and an adapter can run on the
ground station, on the companion computer or next to the service.

* :mod:`arcf.adapters.mavlink`: the service as one MAVLink camera per video stream (the camera
  protocol's tracking commands and ``CAMERA_TRACKING_IMAGE_STATUS``), ``arcf-mavlink``.
* :mod:`arcf.adapters.ros2`: a ROS 2 node on rmw_zenoh: ``CompressedImage`` topics in,
  ``Detection2DArray`` out, sessions from a topic, ``arcf-ros2``.
"""

"""ROS 2 messages for the robot ecosystem: what a detection looks like to ROS 2 tools.

:mod:`service.ros.messages` builds and reads the CDR-encoded ROS 2 messages (with
``rosbags``' serializer and its built-in message definitions, never hand-written CDR):
a detection as a ``visualization_msgs/msg/MarkerArray``, frames as
``sensor_msgs/msg/CompressedImage``, and incoming ``sensor_msgs/msg/Image`` /
``CompressedImage`` samples as images to detect. :mod:`service.ros.recording` writes them
into MCAP files (``mcap``'s writer) that Foxglove and ``ros2 bag`` play.

Import the submodules directly; this package imports nothing, so that the ``dlo`` commands
that do not record pay nothing for ``rosbags``.
"""

"""The ROS 2 gateway: Nav2 robots over rmw_zenoh or zenoh-bridge-ros2dds as robots of a cloud.

``robocloud ros2`` (docs/ros2.md)::

    robots_file.py   the robots file: each robot's endpoint, scheme, distro, offset, capabilities
    interfaces.py    the ROS 2 messages it uses, as .msg text, per distro
    cdr.py           the gateway's CDR codec, built from that text
    naming.py        rmw_zenoh's and the bridge's keys, liveliness tokens, the attachment
    robot.py         one robot: its topics read as a State, its task followed (no I/O)
    link.py          one robot's own Zenoh session: what it reads, the action's requests
    gateway.py       the robots together, the cloud's commands, the states out
    command.py       the command line
    standin.py       a stand-in Nav2 robot's command (``python -m ...ros2.standin``)
    standin_robot.py the stand-in robot itself (its messages in standin_cdr.py, with pycdr2)
"""

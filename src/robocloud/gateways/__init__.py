"""Gateways: robots that do not speak the robot protocol made robots of a cloud.

Layer: outer, like ``sim``: a gateway uses ``fleet`` (the protocol's messages
and keys) and ``domain``, and nothing else of robocloud uses a gateway.

One folder a gateway (``vda5050/``, ``nxt/``, ``ros2/``); what they share is
here, below all three::

    zenoh_side.py       their robots on Zenoh: a robot's keys each, or a fleet gateway's
    command_common.py   the flags, checks and run every gateway command has
    json_file.py        their JSON files (capabilities, bricks, robots) read and checked
"""

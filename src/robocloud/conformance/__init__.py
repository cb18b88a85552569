"""The robot protocol's conformance kit: a stand-in IaaS that drives one robot through the rules.

``robocloud robot-check`` (``robocloud.cli.robot_check``) runs it. ``kit.RobotCheck``
runs the scenarios, ``rules.py`` holds what a robot is held to (the rules, their
sections of docs/protocol.md, the schema checks), ``transport.py`` the Zenoh side.
Layer: outer, like ``sim``: it uses ``fleet`` only.
"""

from robocloud.conformance.kit import RobotCheck
from robocloud.conformance.rules import RULES, Result, Timing

__all__ = ["RULES", "Result", "RobotCheck", "Timing"]

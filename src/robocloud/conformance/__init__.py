"""The robot protocol's conformance kit: a stand-in IaaS that drives one robot through the rules.

``robocloud robot-check`` (``robocloud.cli.robot_check``) runs it; ``kit.RobotCheck``
is the engine. Layer: outer, like ``sim``: it uses ``fleet`` only.
"""

from robocloud.conformance.kit import RULES, Result, RobotCheck

__all__ = ["RULES", "Result", "RobotCheck"]

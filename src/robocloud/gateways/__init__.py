"""Gateways: robots that do not speak the robot protocol made robots of a cloud.

Layer: outer, like ``sim``: a gateway uses ``fleet`` (the protocol's messages
and keys) and ``domain``, and nothing else of robocloud uses a gateway.
"""

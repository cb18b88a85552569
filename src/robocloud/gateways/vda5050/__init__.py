"""The VDA 5050 gateway: the AGVs of an MQTT broker as robots of a cloud (``robocloud vda5050``).

::

    capabilities.py   the capabilities file: capability -> VDA 5050 action, kind, time, cost
    messages.py       VDA 5050 2.x messages: what the gateway reads, what it writes
    agv.py            one AGV: its VDA 5050 state read as a robot's State, its order's progress
    zenoh_side.py     the robots on Zenoh: a command queryable and a state publisher each
    gateway.py        MQTT in and out, commands turned into orders and instant actions
    command.py        the command line
"""

"""The NXT gateway: LEGO Mindstorms NXT bricks as robots of a cloud (``robocloud nxt``).

The thesis's own robots (a Tribot that grabs, two base robots with light
sensors), reached over Bluetooth with LEGO's direct commands. docs/nxt.md
says what an operator connects.

::

    telegrams.py   the direct-command telegrams: encode, decode, frame (no I/O)
    transport.py   the link to a brick: RFCOMM for a real one, TCP for a stand-in
    bricks.py      the bricks file: reach, build, sensors, start pose, capabilities
    battery.py     millivolts -> percent (the curves)
    odometry.py    the pose from the drive motors' tachometers (dead reckoning)
    brick.py       one brick as a robot: its state, its task's movements (no I/O)
    driver.py      one brick's I/O: its link, its readings, its motors
    gateway.py     the bricks on Zenoh: commands in, states out
    command.py     the command line
    standin.py     a stand-in brick on a TCP socket (``robocloud nxt-brick``)
"""

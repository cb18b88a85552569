"""robocloud: robot fleets of several providers federated into one robotic IaaS.

The layers, from the inside out: ``domain`` (pure data and rules), ``selection``
(the coalition selection pipeline of the thesis), ``storage``, ``fleet``,
``federation``, ``iaas``, and the outer ``sim``, ``wildfire`` and ``cli``.
An inner layer never imports an outer one.
"""

__version__ = "0.1.0"

"""robocloud's benchmarks: ``python -m benchmarks.run`` (``make bench``).

Each section measures one part of the system on this machine and writes its
table and figures under ``benchmarks/results/``. Benchmarks are not tests:
they report figures and the goals they meet or miss, and never fail a build.
"""

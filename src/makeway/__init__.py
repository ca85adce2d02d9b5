"""makeway — notice an active emergency vehicle, localize it, keep the belief stable, and make way.

The package follows the data flow (SPEC §7): ``sense`` → ``perceive`` → ``track`` → ``fuse`` →
``decide`` → ``plan`` → ``control``, with typed messages between stages in :mod:`makeway.messages`.
"""

__version__ = "0.1.0"

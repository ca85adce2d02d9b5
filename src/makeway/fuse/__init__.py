"""Fusion stage: observations of an emergency vehicle → EV track → the belief the yield decision
reads (SPEC §7).

* :class:`BeliefSource` — the one interface every source of the belief implements;
* :class:`SirenTrackFusion` — the EV track from what the siren listener hears;
* :class:`MultiEVFusion` — several EVs' tracks from siren, light and V2X observations at once;
* :func:`classify_relation` — behind / ahead / oncoming / crossing from position and heading;
* :class:`ObstacleLinker` — which camera vehicle track each EV belief is (its obstacle id).
"""

from makeway.fuse.multi_ev import FusedBeliefSource, MultiEVFusion
from makeway.fuse.obstacles import ObstacleLinker, ObstacleLinkerConfig
from makeway.fuse.relation import classify_relation
from makeway.fuse.siren_track import SirenTrackFusion
from makeway.fuse.source import BeliefSource

__all__ = [
    "BeliefSource",
    "FusedBeliefSource",
    "MultiEVFusion",
    "ObstacleLinker",
    "ObstacleLinkerConfig",
    "SirenTrackFusion",
    "classify_relation",
]

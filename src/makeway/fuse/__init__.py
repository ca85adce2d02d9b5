"""Fusion stage: observations of an emergency vehicle → one EV track and the belief the yield
decision reads (SPEC §7)."""

from makeway.fuse.relation import classify_relation
from makeway.fuse.siren_track import SirenTrackFusion

__all__ = ["SirenTrackFusion", "classify_relation"]

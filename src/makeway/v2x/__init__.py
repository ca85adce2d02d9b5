"""Vehicle-to-everything alerts, shared by the roadside unit and the car (issue 27, SPEC §5).

* :mod:`~makeway.v2x.message` — the emergency-vehicle alert (ETSI DENM / SAE J2735 fields) and its
  canonical, versioned binary schema;
* :mod:`~makeway.v2x.security` — ECDSA P-256 signatures, unit certificates from a local root, the
  car's trust store, revocation list, freshness window and replay cache;
* :mod:`~makeway.v2x.transport` — zenoh peer-to-peer publish/subscribe keyed by road segment;
* :mod:`~makeway.v2x.belief` — verified alerts → the car's :class:`~makeway.messages.EVBelief`.

Modules are imported on demand: ``transport`` needs zenoh and ``security`` cryptography.
"""

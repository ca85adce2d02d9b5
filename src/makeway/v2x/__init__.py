"""Vehicle-to-everything alerts, shared by the roadside unit and the car (issue 27, SPEC §5).

* :mod:`~makeway.v2x.message` — the emergency-vehicle alert as an ETSI DENM (cause code 95) in
  UPER, canonical, with pycrate's ASN.1 codec as the reference;
* :mod:`~makeway.v2x.security` — the DENM signed as IEEE 1609.2 SignedData (COER, ECDSA P-256),
  unit certificates from a local root, the car's trust store, revocation list, freshness window
  and replay cache;
* :mod:`~makeway.v2x.transport` — zenoh peer-to-peer publish/subscribe keyed by road segment;
* :mod:`~makeway.v2x.belief` — verified alerts → the car's :class:`~makeway.messages.EVBelief`.

Modules are imported on demand: ``transport`` needs zenoh, ``security`` cryptography, and the
reference codecs pycrate.
"""

"""Roadside camera work (seed 001's infrastructure-enabled autonomy): where on the road a pixel of a
fixed pole camera is.

* :mod:`makeway.roadside.geodesy` — WGS-84 latitude/longitude ↔ a local metric frame (ENU).
* :mod:`makeway.roadside.transform` — the transformation-based method: a box's ground-contact point
  back-projected through ``K[R|t]`` onto the road plane.
* :mod:`makeway.roadside.reference` — the location-reference method: pixel ↔ GNSS pairs recorded
  while a car drives the corridor, interpolated with a thin-plate spline.

**Road frame**: the local metric world frame both methods answer in — metres, ENU (``x`` east,
``y`` north, ``z`` up), origin at a reference point on the road whose WGS-84 latitude/longitude the
calibration states; the road surface is the plane ``z = 0``.

Off-car: car-side stages never import this package.
"""

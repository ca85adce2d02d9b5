"""The simulated world the car-side stages are tested in: the vehicle plant, scenarios and their EV,
modelled perception, the roadside traffic camera, sirens, street sounds and the moving-source array.

Car-side stages (sense … control) never import this package; the closed loop (:mod:`makeway.pipeline`)
and the evaluation code do.
"""

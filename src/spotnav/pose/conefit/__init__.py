"""The cone-fit engine: one model of the edge points, one residual with its Jacobian, one robust fit.

Every precise estimate in spotnav is a cone problem: localizing a frame, tracking it, calibrating the geometry from
known poses and fitting the eye's radius over a sequence differ only in which parameters are free. Its modules, in
the order they build on each other: :mod:`~spotnav.pose.conefit.parameters` (the geometry's parameters, their
units, priors and mapping to a setup), :mod:`~spotnav.pose.conefit.model` (the compiled residual and Jacobian),
:mod:`~spotnav.pose.conefit.problem` (the edge points and the problem), :mod:`~spotnav.pose.conefit.covariance`
(how well a fit knows its parameters), :mod:`~spotnav.pose.conefit.solution` (a fitted problem) and
:mod:`~spotnav.pose.conefit.solvers` (the robust recipe, :func:`~spotnav.pose.conefit.solvers.fit_cones`).
"""

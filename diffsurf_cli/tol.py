"""Tolerances used across diffsurf, in one place (as trimesh's ``tol``)."""

#: Relative gap below which a contact is called closed ("contact" status, [33]); relative to
#: the local node spacing of the support.
CONTACT = 1e-9
#: Newton stopping tolerance on the in-plane step, relative to the local node spacing.
NEWTON_STEP = 1e-13
#: Newton iteration limit for the proximal point [30].
NEWTON_MAX_ITER = 30
#: Re-centring iteration limit and tolerance (relative to node spacing) for the MLS projection.
RECENTRE_MAX_ITER = 30
RECENTRE_STEP = 1e-12
#: Reciprocal condition number of the scaled moment matrix below which a fit is refused.
RCOND_MIN = 1e-12
#: Floor of (rho/R)^2 for the singular (interpolating) weight, so a contactor on a node stays finite.
SINGULAR_FLOOR = 1e-14

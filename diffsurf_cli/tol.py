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
RECENTRE_STEP = 1e-10
#: Where the support or frame selection ties (a point equidistant from two nodes) the surface
#: has tiny jumps, and re-centring cycles between two points ~1e-7 spacings apart instead of
#: converging. A move that stops shrinking below this (relative to spacing) is accepted: it is
#: far below the approximation error (~1e-4 spacings at practical resolutions).
RECENTRE_STALL = 1e-5
#: Reciprocal condition number σ_min/σ_max of the weighted basis matrix W^½ P, columns
#: equilibrated, below which a support is refused (retried 1.5x wider, else 'outside'), per
#: basis. Measured on open half cylinders: cubic fits below 1e-3 were off by up to a fifth of
#: the node spacing; quadratic fits near the open ends of sample_meshes/cylinder.msh (two rows of
#: nodes in the support) were off by up to 0.17 spacings below 3e-4 and 0.04 below 1e-3, and by
#: at most 0.004 above it (10,000 points sampled near its facets), so quadratic fits below 1e-3
#: are refused too.
RCOND_MIN = {"linear": 1e-4, "quadratic": 1e-3, "cubic": 1e-3}
#: Columns of the weighted basis matrix are equilibrated to unit norm, but not by more than
#: 1 / EQUILIBRATION_FLOOR relative to the largest: a legitimate column (s³ over nodes within a
#: tenth of R) is 1e-3 of it, while a column of round-off (t on a support that lies on a line,
#: 1e-17) must not look like an independent one (it made collinear supports well conditioned).
EQUILIBRATION_FLOOR = 1e-8
#: Floor of (rho/R)^2 for the singular (interpolating) weight, so a contactor on a node stays finite.
SINGULAR_FLOOR = 1e-14
#: Largest supported magnitude of target coordinates and smallest supported node spacing
#: (targets beyond are refused). Fourth powers of lengths (squared covariances in the kernel's
#: local frames, squared norms of facet areas) leave float64 near 1e±77, where the results
#: were measured to drift (1 % at 1e-80); any unit system (m, mm, µm, km) is decades inside.
COORDINATE_MAX = 1e50
SPACING_MIN = 1e-50

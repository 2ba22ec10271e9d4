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
#: Where a support cannot determine the full basis, reduced bases are fitted (basis.REDUCED).
#: Those constant across (a ruled extrusion of a row of nodes along e3 x a) need a frame that
#: the row itself does not fix: they are used where the nodes that fix the frame (a local
#: frame's ball; the whole target for the global frame) spread in two in-plane directions,
#: the smaller variance at least RULED_SPREAD of the larger (a straight row of nodes without
#: facets leaves e3 anywhere around it: its gap would have an arbitrary sign).
RULED_SPREAD = 1e-4
#: The direction a reduced basis is turned along (its a axis): a support whose weighted
#: in-plane variance across its principal direction is below ROW_VARIANCE of the variance
#: along it is a row, along that direction; else two rows where the polynomial of the
#: quadratic basis that vanishes on the support (its least singular vector) has a quadratic
#: part of rank one within STRIP_RANK (|μ2| <= STRIP_RANK |μ1|: (b - b1)(b - b2) on two straight
#: rows), along its null direction; else the support has no direction (a corner of few nodes,
#: a ring) and only the plane [1, a, b], which needs none, may be fitted. (A weighted PCA alone
#: is not enough: a two-row support about as long as it is wide is nearly isotropic, and its
#: principal direction can come out across the rows.)
ROW_VARIANCE = 1e-2
STRIP_RANK = 0.05
#: Columns of the weighted basis matrix are equilibrated to unit norm, but not by more than
#: 1 / EQUILIBRATION_FLOOR relative to the largest: a legitimate column (s³ over nodes within a
#: tenth of R) is 1e-3 of it, while a column of round-off (t on a support that lies on a line,
#: 1e-17) must not look like an independent one (it made collinear supports well conditioned).
EQUILIBRATION_FLOOR = 1e-8
#: Floor of (rho/R)^2 for the singular (interpolating) weight, so a contactor on a node stays
#: finite.
SINGULAR_FLOOR = 1e-14
#: Largest supported magnitude of target coordinates and smallest supported node spacing
#: (targets beyond are refused). Fourth powers of lengths (squared covariances in the kernel's
#: local frames, squared norms of facet areas) leave float64 near 1e±77, where the results
#: were measured to drift (1 % at 1e-80); any unit system (m, mm, µm, km) is decades inside.
COORDINATE_MAX = 1e50
SPACING_MIN = 1e-50

# --- the projection (diffsurf_cli.mls): read by the compiled engine at every call ----------
#: A proximal point farther than this many local node spacings from every support node is off
#: the target (beyond an open boundary): status 'outside'.
OUTSIDE_SPACINGS = 1.0
#: A proximal point beyond the in-plane hull of its support by more than this many spacings
#: is past an open edge of the target: 'outside'.
HULL_SPACINGS = 0.25
#: Default domain of influence per basis, in local node spacings (measured: benchmarks/accuracy.py
#: and docs/presets.md "Defaults, and why"): a cubic fit at 2.0 spacings has too few nodes near
#: open edges.
DEFAULT_RADIUS = {"linear": 2.0, "quadratic": 2.0, "cubic": 3.0}
#: Factor on R (and on k², with 'knn' support) for a second try when the first support is too
#: thin for the basis, or its fit carries the proximal point off the target.
ENLARGE = 1.5
#: With 'knn' support, R is this factor times the in-plane distance of the farthest of the k
#: nodes, so all k keep a positive weight.
KNN_RADIUS_FACTOR = 1.2
#: Local frames are fitted by PCA over a ball this many R wide, so the support does not change
#: abruptly with the frame.
FRAME_BALL = 1.5
#: With local frames, support nodes whose normal is more than this angle away from the target's
#: normal near the reference point belong to another sheet of the target (the far side of a
#: thin tube or plate) and are left out. Deliberately not a round angle: regular meshes (steps
#: of 7.5°, 15°, 30°, 45°, 60°) would put node normals exactly on the threshold.
SHEET_ANGLE_DEG = 63.0
#: Node spacing at a point: its SPACING_NEIGHBOURS + 1 nearest nodes, weighted by
#: (1 - d²/d_max²)² (d_max the distance of the last: zero weight for it and for any node tied
#: with it, so no tie-break matters), average their own spacing (the mean distance to their
#: SPACING_NEIGHBOURS nearest nodes), normal and position (the reference point's foot).
SPACING_NEIGHBOURS = 4
#: X3 = f(X1, X2) cannot represent the target where it turns vertical or folds back over the
#: frame (a closed or wrapped target under a forced global frame, whose far sheet lies under the
#: near one; a support so wide, or a k so large, that it wraps around a faceless closed target):
#: a fit mixes the sheets. A support node is steep (the point 'steep') when its normal (from
#: the facets, or else the unsigned `frame.pca_normals`), or over a global frame a chord to one
#: of its FOLD_NEIGHBOURS nearest nodes in plan that rises more than FOLD_MIN_RISE of its
#: spacing, is more than FOLD_SLOPE_DEG from e3.
#: Measured on a half cylinder seen from its mean plane: the gap error of the global frame grows
#: from 1e-4 to 1e-2 spacings between 0 and 75 degrees (where it stops converging with
#: refinement) and is 100 times that of local frames there; the limit is above the 72 degrees
#: of a spherical cap the global frame still handles, and the rise keeps near-duplicate or
#: noisy nodes, whose chords are steep but short, from counting.
FOLD_SLOPE_DEG = 80.0
FOLD_MIN_RISE = 0.5
FOLD_NEIGHBOURS = 8
#: frame 'auto' keeps the global frame only while every facet normal is within this angle of
#: e3: beyond it the height field X3 = f(X1, X2) gets too steep to fit accurately.
AUTO_MAX_SLOPE_DEG = 60.0
#: A node's nearest nodes lie on a line (`frame.pca_normals`: no plane, no normal) when their
#: spread across the line is below this fraction of their spread along it (eigenvalues of
#: their covariance): round-off of a straight row of nodes.
COLLINEAR_SPREAD = 1e-12
#: The box of cells the local spacing's search (`_search.nearest`) reads first, in cells
#: around the point (a 2x2x2 box of cells mostly, where a search by layers reads 3x3x3); the
#: k-d tree answers where it holds fewer than the nodes wanted.
NEAR_REACH_CELLS = 0.75
#: Relative round-off margins of the searches' bounds: a cell's bound (`knn`) and a k-d tree
#: box's (`tree_knn`) are loosened by this much of the coordinates' magnitude, so a node on a
#: bound is never skipped (the same nodes are found whatever the rounding of the bound).
SEARCH_MARGIN = 1e-9
TREE_MARGIN = 1e-12
#: Width of the truncated Gaussian weight, in units of R.
GAUSS_WIDTH = 0.4
#: Fixed, generic directions that fix e1 of a local frame in its tangent plane (the fit is
#: invariant under rotations about e3, so e1 only has to be a deterministic function of e3).
E1_GUIDE = (0.8, 0.52, 0.3)
E1_GUIDE_ALT = (-0.3, 0.6, -0.74)
#: The reported `rcond` (Projection.rcond, the CLI's rcond column) is a lower bound on
#: σmin/σmax of the equilibrated W^½P: rcond_F = 1/(‖R‖_F ‖R⁻¹‖_F) of its triangular factor,
#: with rcond_F ≤ σmin/σmax ≤ n rcond_F (n basis terms). Where the bound cannot decide
#: against RCOND_MIN (RCOND_MIN/n ≤ rcond_F < RCOND_MIN) the exact σmin/σmax is computed and
#: reported instead, so `rcond >= RCOND_MIN` holds exactly when σmin/σmax >= RCOND_MIN.

# --- the rigid target (diffsurf_cli.element.rigid) -----------------------------------------
#: Radius of each node's blending weight in the rigid target's fixed surface, in that node's
#: spacings (β). Measured by `benchmarks/rigid_speed.py --beta` on the 1.6k-node sphere (gap
#: error max / RMS in spacings; CPU per contactor, the projection's 2.9 µs in the same run):
#: 1.25: 3.3e-5 / 1.5e-5, 5.3 µs; 1.5: 3.1e-5 / 1.5e-5, 5.9 µs; 1.75: 2.5e-5 / 1.3e-5, 6.5 µs;
#: 2.0: 7.4e-6 / 3.8e-6, 7.9 µs; 2.5: 5.6e-5 / 4.4e-5, 10.5 µs. On a 24-quad cylinder the max
#: error is 4.2e-4 at 1.25-1.5, 3.2e-4 at 2.0, 1.6e-4 at 2.5 (the projection's: 1.3e-3): no β
#: is best everywhere, the cost grows with β², and every point of the surface must be reached
#: by some node's weight on graded meshes: 1.5.
RIGID_BLEND_SPACINGS = 1.5

# --- the faceted target (diffsurf_cli.facet): read by its compiled engine ------------------
#: Projected-Newton iteration limit on a bilinear quad, and the step on [0, 1]² below which
#: it stops (Newton converges quadratically: the next step would be ~1e-28).
QUAD_ITERATIONS = 25
QUAD_STEP = 1e-14
#: ξ within this of a bound of [0, 1]² (or of a + b = 1) is on the facet's edge or vertex:
#: the gap there is signed by the pseudonormal (as `free_parameters`, the element's).
EDGE_EPS = 1e-12
#: Contactors farther than FAR_RADII target radii from its centre rank candidate facets by
#: |x|² - 2 p·x (|p - x|² less |p|², which would swallow the target's size in rounding);
#: beyond PROXY_RADII the search uses a stand-in at PROXY_RADII in the same direction (the
#: ranking then changes by radius / PROXY_RADII, below rounding), so no square overflows.
FAR_RADII = 1e3
PROXY_RADII = 1e20

# --- the patches (diffsurf_cli.patches) ----------------------------------------------------
#: Facets are coplanar (one flat face) when their normals' cosine is at least this (1e-5
#: radians: round-off of a CAD face's mesh, far below any curved mesh's facet angle).
FLAT_COS = 1.0 - 5e-11
#: A coarse smooth curve (issue 35: a tube of 8 facets around turns 45° at every edge, past
#: the feature angle) is told from a crease by the pattern of its bends (`segment.creases`):
#: an edge past the feature angle is no crease where it turns by at most CURVE_MAX_DEG and the
#: facets on either side of it turn, across themselves and about its line, by between
#: CURVE_RATIO[0] and CURVE_RATIO[1] times its angle in the same sense (a facet of each side's
#: vertex ring does). Measured (`segment.bend_pattern`): coarse tori and spheres, 0.76 to
#: 1.28 (trimesh tori 16x8 and 24x8: 0.98 to 1.05); a fillet of two cells between flat faces,
#: 0.44 to 0.58 (kept a crease: its flat faces do not turn); a helical thread's flanks, 1.8
#: to 3.7; a box, a chamfer, a thin wall, a cap's rim: 0 (a flat side). CURVE_MAX_DEG sits
#: between 7 facets around (51.4°) and a hexagon's 60° (a box of one facet a face turns 90°
#: at every edge, as a tube of 4 facets around would: a crease).
CURVE_MAX_DEG = 58.0
CURVE_RATIO = (2.0 / 3.0, 1.5)
#: A facet of the ring counts only where its normal, projected across the edge's line, keeps
#: at least this length (a facet whose normal runs along the edge, a box's third face at a
#: corner, turns about no axis of it).
CURVE_AXIS_MIN = 0.5
#: A sharp edge (a crease, `segment.creases`) is a crease of the CAD, where two faces meet at
#: an angle (C0: a thread's flank meeting its core, a box's edge), and not a fillet that one
#: cell cannot resolve (C1: two parallel bends of the same sense either side of a strip of
#: facets), where no facet of either side's vertex ring turns about its line by this much of
#: its angle or more in the same sense (`segment.flat_sided`; `surface.corner_normals` gives
#: the nodes of such a crease each side's own normal where it ends inside one smooth region).
#: Measured (`segment.bend_pattern`) at the sharp edges that end inside one smooth region: a
#: helical thread's flanks and core (`testing.gmsh_scenes.thread`), 0 to 0.14 on 341 of 346
#: edges (0.25 and 0.32 on two more); the under-resolved fillets of gmsh's Solid_56 and
#: linkrods (`benchmarks/real_parts.py`, first and second order and STL), 0.23 and more
#: (0.8 to 3 on most).
CREASE_SIDE_RATIO = 0.2
#: A crease of the CAD below the feature angle: an edge that turns by at least this much
#: (degrees), at which neither side turns (`segment.flat_sided`) and not both turn back (a
#: zigzag: `segment.cad_creases`), is sharp though no feature by its angle alone. One flank
#: of `testing.gmsh_scenes.thread` meets its core at 21° to 40°, and the core between two
#: turns is about one cell wide: in its STL the region's normal at the root averaged the
#: two faces, and the diffuse surface, its guard's sides and the curved cells rounded a
#: corner of the CAD (2 wrong signs where the facets have none, `benchmarks/refinement.py`).
#: A coarse smooth curve turns on both sides (a sphere of 2 elements per radius, 22°), a
#: fillet's first facet on its fillet's side, a second-order fillet's corner facets under
#: one cell zigzag (34.5°): none is a crease.
CREASE_MIN_DEG = 20.0
#: Four second-order cells are one cell cut in four on its own map (`segment.cut_on_map`,
#: issue 34) where each of their nodes is within this, relative to the parent cell's size
#: (its corners' largest distance), of the parent's map at the node's parameter. A refinement
#: on the map puts them there to round-off (3e-15 measured: gmsh spheres of triangle6, quad8,
#: quad9 at 3 to 16 elements per quarter circle) and a file's printed coordinates to its digits
#: (8 significant digits: 1e-8 of a coordinate, 1e-6 of a cell a hundredth of the part). A
#: refinement that moved them onto the CAD moved them by the cell's own error, falling as h²
#: relative to it: the same spheres with the new nodes on the sphere, 3e-4 to 2e-3 at 3
#: elements, 2e-5 to 2e-4 at 8, 6e-7 to 8e-5 at 16 (a few of the finest cells then pass: their
#: nodes add less than 1e-5 of the cell, nothing the fit could use). The parent's nodes within
#: this of its corners' plane make it flat: a flat face's cells, left as they are (`segment._flat`).
CUT_ON_MAP = 1e-5

# --- guards ----------------------------------------------------------------------------------
#: Floor of a length or an area before dividing by it (a degenerate facet, a target of one
#: point): far below any supported geometry (SPACING_MIN), it only turns 0/0 into 0 instead of
#: NaN.
TINY = 1e-300

# --- reading targets (diffsurf_cli.io) -----------------------------------------------------
#: Nodes of an STL (or of a triangle soup in any format) closer than this, relative to the
#: bounding-box diagonal of the target's nodes, are one node (io.mesh.merge_vertices). An STL
#: stores each facet's own copy of its vertices; copies that the exporter's round-off moved
#: apart leave the facets unconnected, and the facet method's signs wrong at their edges.
#: trimesh's models/octagonal_pocket.stl has 33 such pairs, up to 1.3e-15 of its diagonal
#: apart, and its closest distinct vertices are 1.2e-5 of it apart. Copies that a binary
#: (float32) STL rounded apart are one float32 step apart, 6e-8 to 1.2e-7 of the coordinate's
#: magnitude. 1e-6 is above those (for a part within a few of its sizes of the origin), 12
#: times below the pocket's closest distinct vertices, and far below any facet worth
#: projecting on (trimesh's merge_vertices rounds at 1e-8 absolute: 1e-8 of a part 1 m in
#: size, 1e-10 of one 100 mm in size in mm).
MERGE_VERTICES = 1e-6

# --- the patched surface (diffsurf_cli.patches): read by its compiled pass ------------------
#: Candidate patches of a contactor are those of the facets sharing a node with its faceted
#: foot's facet f0; a patch other than f0's is tried only where its box is within d0 + this
#: many local node spacings (d0 the contactor's distance to the facets): the diffuse surface
#: departs from the facets by the sagitta (h²κ/8, a fraction of h).
CANDIDATE_SPACINGS = 0.5
#: A patch's proximal point whose closest point on the patch's facets is on a sharp edge and
#: off it, along the facet, by more than this many spacings is past the patch's edge
#: (invalid). Round-off scale: on a flat patch past a sharp edge the facets' edge point is the
#: exact answer.
OVERSHOOT_SPACINGS = 1e-6
#: The same past a smooth edge between two patches split by their tags only (a fillet's
#: tangent edge): the diffuse surface's offset from the facets there (the sagitta, curving
#: across the edge) gives an apparent overshoot of sagitta x sin(half the facet angle), and
#: the next patch continues the surface; a tenth of a spacing past it, a convex quadratic
#: departs from its tangent by κ h²/200 at most, below the fit's error.
SMOOTH_OVERSHOOT_SPACINGS = 0.1
#: frame 'auto' per patch: the global mean plane for a flat patch (every facet within this
#: angle of it: exact there), else local frames. Measured on the fillet box
#: (benchmarks/feature_targets.py): on its quarter-cylinder fillets, 7.5x the facets' accuracy
#: (RMS) with the global frame, 44x with local frames.
FLAT_PATCH_DEG = 1.0
#: The guard (patches.surface.guard_bounds): a diffuse answer may differ from the facets' gap
#: by GUARD_SAG_MARGIN times the largest chordal sag of the facets around the faceted foot,
#: plus GUARD_FLOOR node spacings (round-off: a flat face is reproduced to ~1e-15 of its
#: size), and its normal from the foot facet's by GUARD_NORMAL_MARGIN times the largest angle
#: between that facet's normal and its smooth neighbours', plus GUARD_NORMAL_FLOOR_DEG.
#: Measured on smooth targets (/tests/test_guard.py's shapes): a diffuse answer more accurate
#: than the facets differs from them by at most 1.6 sags (a gmsh sphere of first order), one
#: 4x less accurate (a torus of 8 facets around) by up to 7.8. On the real-parts battery
#: (benchmarks/real_parts.py; rows failing its criteria "no more wrong signs or gross errors
#: than the facets" / "RMS 5x the facets'", with the envelope alone): 1.5: 2 / 9; 1.75: 2 / 8;
#: 2.0: 6 / 9. The first is the guard's purpose.
GUARD_SAG_MARGIN = 1.75
GUARD_FLOOR = 1e-6
#: ... and on the side where the facets around the foot do not bend (a smooth surface that
#: convex facets interpolate lies above them), only this fraction of their sag (a fit is no
#: interpolation). Measured (guard off) on tests/test_guard.py's shapes: 0 where diffsurf is
#: accurate; up to 0.24 on a torus of 8 facets around, where it is 4x less accurate than the
#: facets. On the real-parts battery, rows failing "no more wrong signs or gross errors than
#: the facets": 2 of 86 with the envelope alone (GUARD_SAG_MARGIN on either side); 2 at 0.5
#: and at 0.25 while creases' bends counted; 1 at 0.25 without them (guard_bounds).
GUARD_OTHER_SIDE = 0.25
GUARD_NORMAL_MARGIN = 1.0
GUARD_NORMAL_FLOOR_DEG = 0.01

#: The support follows the mesh (issue 19, item 2): on a contactor's own patch, over a quad
#: (the faces of hexahedral meshes), the local node spacing (the unit of R) is at least this
#: fraction of the quad's longest edge. The spacing of the nearest nodes alone is the short
#: side's: an elongated face (12.5 x 2.5 on a cylinder) got a support one row long, answered
#: no better than the facets, or not at all between rows. Measured on cylinders of radius 30
#: and 50 with quads 12.5 x 2.5, long side around and along the axis (largest gap error,
#: facets 0.39, 0.016, 0.65, 0.026): 0.5 and below leave the next row at the edge of R (0.39
#: and 0.65 around); 0.55 gives 0.014, 0.0021, 0.069, 0.011; 0.6 0.014, 0.0030, 0.069, 0.016;
#: 0.7 loses points along. Isotropic meshes are unchanged (the mean distance to the 4 nearest
#: nodes is about an edge). Not over triangles: a CAD STL's slivers span a whole face, whose
#: rows the reduced bases fit.
SUPPORT_FACET_FRACTION = 0.55

# --- threads --------------------------------------------------------------------------------
#: The crossover of each compiled entry point with a parallel loop (`threads.threads_for`): a
#: batch of fewer contactors runs on the calling thread in a plain loop, without an OpenMP
#: parallel region; from it on, two threads (one per half a crossover of contactors, up to
#: OpenMP's count). Measured on the filleted box of benchmarks/patch_speed.py (10k nodes), a
#: 2-CPU virtual machine (AMD EPYC), wall time per call on 1 thread against 2, with
#:
#:     OMP_NUM_THREADS=2 python benchmarks/crossover.py
#:
#: (benchmarks/results/crossover.txt): the other thread asleep at every call
#: (`diffsurf_cli.SPINCOUNT`; the first call after a solver's own work finds it so whatever
#: the wait policy), two threads start to win where a batch is about 1 ms of one thread's work
#: (two runs): project 512 contactors, project_with 1024, pass 128-256, facets 1024, supports
#: 2048-4096, elements 32-128, rigid 64-128, nearest 256-1024, facet_elements 2048-4096 (one
#: run: the fastest calls, then the median); below that the woken thread arrives when the work
#: is done. The larger figure of the two runs is kept. With libgomp's
#: default spinning (GOMP_SPINCOUNT=300000), calls back to back find it awake and two threads
#: win from 8-32 contactors, at the cost of a CPU kept busy between calls.
PARALLEL_MIN = {
    "project": 512,        # mls._projection.Target.project
    "project_with": 1024,  # mls._projection.Target.project_with
    "pass": 256,           # patches._pass.PatchedPass.project
    "facets": 1024,        # facet._engine.project
    "elements": 128,       # element._element.elements
    "facet_elements": 4096,  # element._element.facet_elements
    "supports": 4096,      # element._element.supports
    "rigid": 128,          # element._rigid.closest_points
    "nearest": 1024,       # mls._search.nearest_distances
    "quadric": 128,        # mls._quadric.Quadrics.project: ~25 us a contactor (a re-centring
    #                        loop), so a region's 15-50 us wake-up pays from a few; as elements
}

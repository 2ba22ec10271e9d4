# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False
"""The diffuse contact element [§4.2-4.3] in compiled code: g, 𝒩 = ∂g/∂u, ℳ = ∂²g/∂u².

One element per contactor, in parallel over contactors (OpenMP `prange`, per-thread scratch
allocated once per call, nothing allocated per element). Derivatives are exact and structured,
as the paper sketches them; the frame, the support and R are the frozen pairing [§4.2].

Change of variables. In the scaled frame X = axes (x - o) / R, with s_i = X1_i - X1^c,
t_i = X2_i - X2^c, and σ = X̄ - X^c (the proximal point relative to the basis centre), the
fit [17] depends on w = (s_i, t_i, Z_i) only, and the gap [32] on (σ, X3^c, f, f,1, f,2):

    G = (σ1 f,1 + σ2 f,2 + X3^c - f) / sqrt(1 + f,1² + f,2²),    D = ½(σ·σ + (X3^c - f)²).

σ is solved by ∂D/∂σ = 0 [30] for given w, so the contactor's X1^c, X2^c enter through the
s_i, t_i alone (∂/∂X1^c = -Σ ∂/∂s_i), and g(u) = R G(σ(w), w(u)).

𝒩: ∂G/∂σ = 0 at the proximal point (x^c - x^d is along ν [30]), so 𝒩 = ∂G/∂w at fixed σ.
f, f,1, f,2 are linear functionals q_jᵀα of α (q_j = p, p,s, p,t at σ), so with
λ = A⁻¹ Σ_j G_{,f_j} q_j (one adjoint), ∂G/∂w = G_{,X3} e_X3 + λᵀ(∂b - ∂A α), and node i
touches only its own rank-one term w_i p_i p_iᵀ: ∂b - ∂A α = β_i, a k-vector per unknown.

ℳ: with A = Pᵀ W P, b = Pᵀ W Z [17], ∂α = A⁻¹ β, and
λᵀ∂²α = λᵀ(∂²b - ∂²A α) - γ_aᵀ ∂α_b - γ_bᵀ ∂α_a, γ_a = ∂A_aᵀ λ. ∂²b, ∂²A are
node-diagonal (3x3 blocks), so the cross-node part is Γᵀ Δ (Γ, Δ = ∂α: k x 3n), O(n² k).
The rest is a rank-6 form Vᵀ S V over the rows V = (e_X3, ∂f, ∂f,1, ∂f,2, μ_1ᵀβ, μ_2ᵀβ)
(μ_k = A⁻¹ Σ_j G_{,f_j} ∂q_j/∂σ_k: the σ-derivatives of the gap's functionals), where S
holds the gap's Hessian in (X3^c, f, f,1, f,2) and the implicit-function term
-G_{,wσ} D_{,σσ}⁻¹ D_{,σw} (the paper's 𝒮_l, 𝒯_l, 𝒰, 𝒟_τ [48]-[53]).

Instructions an element (quadratic basis, 1692-node sphere, ~19 support nodes; the command
is in benchmarks/element_speed.py's docstring): 197k (ℳ's rank-(6 + 2k) build is ~45% of it).
ℳ's product XᵀY is formed in register tiles (`ds_rank_upper`), the node blocks' rotations as
two 3x3 products, a node's three Δ = A⁻¹β in one pass (`cholesky_solve3`): on a 16k-node
sphere (~14 support nodes; callgrind) an element with ℳ went from 217k to 132k instructions
(issue 33). `tangent_elements` builds each ℳ into a block in cache and adds it into the CSR
at once (`_assembly.add_block`); `elements(..., reference=True)` keeps the kernel before
(rank-one row updates), which the tests check this one against.

A is factored by Cholesky (it is symmetric positive definite where the fit exists; the
projection judged its conditioning on W^½P already), and α refined once in residual form, as
every β_i is written with the node's residual Z_i - p_iᵀα rather than as ∂b - ∂A α (two
sums that cancel where the fit nearly interpolates). The weight, the basis and the Cholesky
factor are the method's shared steps (mls/_steps.pxd, mls/_linalg.pxd); constants come from
diffsurf_cli.tol at call time.
"""
import numpy as np

from libc.math cimport sqrt, NAN
from libc.stdlib cimport calloc, malloc, free
from libc.stdint cimport int32_t, int64_t
from cython.parallel cimport prange, parallel

from .. import tol
from ..mls import basis as _basis
from ..mls._linalg cimport NTERMS_MAX, cholesky, cholesky_solve, dot
from ..threads import chunk_size, threads_for
from ..mls._weight cimport WeightParams, weight_params, weight_value, weight_derivatives
from ..mls._steps cimport basis_derivatives
from ._assembly cimport (Places, BlockScratch, block_scratch_new, block_scratch_free,
                         add_block)

cdef extern from *:
    """
    /* The upper triangle (in 3 x 3 diagonal tiles: their lower entries too) of M = Xᵀ Y:
       M[a, b] = sum_r X[a, r] Y[r, b] (X: m rows of L, Y: L rows of m, M row stride ldm;
       m a multiple of 3), each entry summed from 0 in r's order (bitwise the rank-one
       updates' sums: no fused multiply-add), in register tiles of 3 rows x 8 columns (GCC
       vectors of 4 doubles: AVX where the CPU has it, a clone of the function chosen at
       load; pairs of SSE2 vectors elsewhere). */
    typedef double ds_v4 __attribute__((vector_size(32), aligned(8)));
    /* y += a x over n entries (the reference kernel's rank-one updates) */
    static inline void ds_axpy(double *restrict y, const double *restrict x, double a,
                               long n) {
        for (long i = 0; i < n; i++) y[i] += a * x[i];
    }
    #if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
    #define DS_CLONES __attribute__((target_clones("avx", "default")))
    #else  /* another compiler or CPU (clang, ARM): one portable version */
    #define DS_CLONES
    #endif
    DS_CLONES
    static void ds_rank_upper(double *M, long ldm, const double *X, const double *Y,
                              long L, long m) {
        for (long a = 0; a < m; a += 3) {
            const double *x0 = X + a * L, *x1 = x0 + L, *x2 = x1 + L;
            double *o0 = M + a * ldm, *o1 = o0 + ldm, *o2 = o1 + ldm;
            long b = a;
            for (; b + 8 <= m; b += 8) {
                ds_v4 c00 = {0, 0, 0, 0}, c01 = {0, 0, 0, 0};
                ds_v4 c10 = {0, 0, 0, 0}, c11 = {0, 0, 0, 0};
                ds_v4 c20 = {0, 0, 0, 0}, c21 = {0, 0, 0, 0};
                for (long r = 0; r < L; r++) {
                    const ds_v4 *y = (const ds_v4 *) (Y + r * m + b);
                    ds_v4 y0 = y[0], y1 = y[1];
                    ds_v4 u = {x0[r], x0[r], x0[r], x0[r]};
                    ds_v4 v = {x1[r], x1[r], x1[r], x1[r]};
                    ds_v4 w = {x2[r], x2[r], x2[r], x2[r]};
                    c00 += u * y0; c01 += u * y1;
                    c10 += v * y0; c11 += v * y1;
                    c20 += w * y0; c21 += w * y1;
                }
                ((ds_v4 *) (o0 + b))[0] = c00; ((ds_v4 *) (o0 + b))[1] = c01;
                ((ds_v4 *) (o1 + b))[0] = c10; ((ds_v4 *) (o1 + b))[1] = c11;
                ((ds_v4 *) (o2 + b))[0] = c20; ((ds_v4 *) (o2 + b))[1] = c21;
            }
            if (b + 4 <= m) {
                ds_v4 c0 = {0, 0, 0, 0}, c1 = {0, 0, 0, 0}, c2 = {0, 0, 0, 0};
                for (long r = 0; r < L; r++) {
                    ds_v4 y0 = *(const ds_v4 *) (Y + r * m + b);
                    ds_v4 u = {x0[r], x0[r], x0[r], x0[r]};
                    ds_v4 v = {x1[r], x1[r], x1[r], x1[r]};
                    ds_v4 w = {x2[r], x2[r], x2[r], x2[r]};
                    c0 += u * y0; c1 += v * y0; c2 += w * y0;
                }
                *(ds_v4 *) (o0 + b) = c0; *(ds_v4 *) (o1 + b) = c1; *(ds_v4 *) (o2 + b) = c2;
                b += 4;
            }
            for (; b < m; b++) {  /* the last 3 columns or fewer */
                double s0 = 0.0, s1 = 0.0, s2 = 0.0;
                for (long r = 0; r < L; r++) {
                    double y = Y[r * m + b];
                    s0 += x0[r] * y; s1 += x1[r] * y; s2 += x2[r] * y;
                }
                o0[b] = s0; o1[b] = s1; o2[b] = s2;
            }
        }
    }
    """
    void ds_rank_upper(double *M, long ldm, const double *X, const double *Y, long L,
                       long m) noexcept nogil
    void ds_axpy(double *y, const double *x, double a, long n) noexcept nogil

cdef enum:
    KMAX = NTERMS_MAX    # the cubic basis
    NV = 6               # rows of V: e_X3, ∂f, ∂f,1, ∂f,2, μ_1ᵀβ, μ_2ᵀβ


cdef struct Params:
    int k
    int ea[KMAX]
    int eb[KMAX]
    WeightParams wp


cdef Params _params(basis, str weight) except *:
    """`basis`: a basis name, or the exponents of a reduced basis (basis.REDUCED: in the frame
    turned along a strip, which the caller passes as the frame)."""
    cdef Params pa
    cdef int j
    exps = _basis.EXPONENTS[basis] if isinstance(basis, str) else tuple(basis)
    if not 0 < len(exps) <= KMAX or max(a + b for a, b in exps) > 3:
        raise ValueError(f"a basis of 1 to {KMAX} terms of degree at most 3, got {exps}")
    pa.k = len(exps)
    for j in range(pa.k):
        pa.ea[j] = exps[j][0]
        pa.eb[j] = exps[j][1]
    pa.wp = weight_params(weight)
    return pa


# --------------------------------------------------------------------------------------------
# the scaled frame
# --------------------------------------------------------------------------------------------

cdef inline void to_local(const double *x, const double *origin, const double *axes,
                          double inv_r, double *out) noexcept nogil:
    """X = axes (x - o) / R."""
    cdef double d0 = x[0] - origin[0], d1 = x[1] - origin[1], d2 = x[2] - origin[2]
    cdef int a
    for a in range(3):
        out[a] = (axes[3 * a] * d0 + axes[3 * a + 1] * d1 + axes[3 * a + 2] * d2) * inv_r


# --------------------------------------------------------------------------------------------
# scratch
# --------------------------------------------------------------------------------------------

cdef struct Scratch:
    double *mem
    double *s          # (cap,) per node: s, t, Z
    double *t
    double *z
    double *w          # (cap, 3) w, dw/dq, d²w/dq²
    double *bas        # (cap, 6k) basis and derivatives at each node
    double *E          # (cap, 9) node-diagonal blocks λᵀ(∂²b - ∂²A α) in (s, t, Z)
    double *X          # (3(cap+1), L) per unknown: V (6), Γ (k), Δ (k)
    double *Y          # (L, 3(cap+1)): S V, -Δ, -Γ, by rows


cdef Scratch *scratch_new(int64_t cap, int k) noexcept nogil:
    cdef Scratch *sc = <Scratch *> malloc(sizeof(Scratch))
    cdef int64_t L = NV + 2 * k, cols = 3 * (cap + 1)
    cdef int64_t size = 6 * cap + 6 * k * cap + 9 * cap + 2 * cols * L
    if sc == NULL:
        return NULL
    sc.mem = <double *> malloc(size * sizeof(double))
    if sc.mem == NULL:
        free(sc)
        return NULL
    sc.s = sc.mem
    sc.t = sc.s + cap
    sc.z = sc.t + cap
    sc.w = sc.z + cap
    sc.bas = sc.w + 3 * cap
    sc.E = sc.bas + 6 * k * cap
    sc.X = sc.E + 9 * cap
    sc.Y = sc.X + cols * L
    return sc


cdef void scratch_free(Scratch *sc) noexcept nogil:
    if sc != NULL:
        free(sc.mem)
        free(sc)


# --------------------------------------------------------------------------------------------
# one element
# --------------------------------------------------------------------------------------------

cdef inline void rotate_block(double *x, const double *axes, int64_t L,
                              int64_t used) noexcept nogil:
    """Three vectors v_0..v_2 (∂/∂X_a; stride L, first `used` entries) ← Σ_a axes[a][b] v_a
    (∂/∂x_b): the chain rule through X = axes (x - o) / R (the 1/R is applied to ℳ at the
    end)."""
    cdef int64_t r
    cdef double v0, v1, v2
    for r in range(used):
        v0 = x[r]
        v1 = x[L + r]
        v2 = x[2 * L + r]
        x[r] = axes[0] * v0 + axes[3] * v1 + axes[6] * v2
        x[L + r] = axes[1] * v0 + axes[4] * v1 + axes[7] * v2
        x[2 * L + r] = axes[2] * v0 + axes[5] * v1 + axes[8] * v2


cdef inline void add_rotated(double *M, int64_t ldm, int64_t r0, int64_t c0, const double *e,
                             const double *axes, bint upper) noexcept nogil:
    """M[r0:r0+3, c0:c0+3] += axesᵀ e axes (only entries on or above the diagonal if upper),
    as two 3x3 products (54 products, not the quadruple sum's 729)."""
    cdef int p, q, a
    cdef double t[9]
    for a in range(3):
        for q in range(3):
            t[3 * a + q] = (e[3 * a] * axes[q] + e[3 * a + 1] * axes[3 + q]
                            + e[3 * a + 2] * axes[6 + q])
    for p in range(3):
        for q in range(3):
            if upper and q < p:
                continue
            M[(r0 + p) * ldm + c0 + q] += (axes[p] * t[q] + axes[3 + p] * t[3 + q]
                                           + axes[6 + p] * t[6 + q])


cdef inline void add_rotated_reference(double *M, int64_t ldm, int64_t r0, int64_t c0,
                                       const double *e, const double *axes,
                                       bint upper) noexcept nogil:
    """`add_rotated` as a quadruple sum (the reference kernel's: `hessian`'s `reference`)."""
    cdef int p, q, a, b
    cdef double acc
    for p in range(3):
        for q in range(3):
            if upper and q < p:
                continue
            acc = 0.0
            for a in range(3):
                for b in range(3):
                    acc += axes[3 * a + p] * e[3 * a + b] * axes[3 * b + q]
            M[(r0 + p) * ldm + c0 + q] += acc


cdef inline void moments(const Params *pa, const double *nodes, const double *c,
                         const double *origin, const double *axes, double inv_r,
                         const int64_t *idx, int64_t n, Scratch *sc, double *A_out,
                         double *b_out) noexcept nogil:
    """Each support node's s, t, Z (centred at the contactor c, scaled frame), weight and
    basis derivatives into sc, and A = Pᵀ W P (upper triangle), b = Pᵀ W Z [17]."""
    cdef int k = pa.k, j, v
    cdef int64_t i
    cdef double X[3]
    cdef double wq[3]
    cdef double si, ti, acc
    cdef double *bas
    # (summed in local arrays, copied out at the end: the compiler then knows that the sums
    # alias nothing)
    cdef double A[KMAX * KMAX]
    cdef double b[KMAX]
    for j in range(k * k):
        A[j] = 0.0
    for j in range(k):
        b[j] = 0.0
    for i in range(n):
        to_local(&nodes[3 * idx[i]], origin, axes, inv_r, X)
        si = X[0] - c[0]
        ti = X[1] - c[1]
        sc.s[i] = si
        sc.t[i] = ti
        sc.z[i] = X[2]
        weight_derivatives(&pa.wp, si * si + ti * ti, wq)
        sc.w[3 * i] = wq[0]
        sc.w[3 * i + 1] = wq[1]
        sc.w[3 * i + 2] = wq[2]
        bas = sc.bas + 6 * k * i
        basis_derivatives(k, pa.ea, pa.eb, si, ti, bas)
        for j in range(k):
            acc = wq[0] * bas[j]
            b[j] += acc * X[2]
            for v in range(j + 1):  # the upper triangle, A_vj (v <= j)
                A[v * k + j] += acc * bas[v]
    for j in range(k * k):
        A_out[j] = A[j]
    for j in range(k):
        b_out[j] = b[j]


cdef inline void refine(const Scratch *sc, int k, int64_t n, const double *A,
                        const double *dchol, double *alpha) noexcept nogil:
    """One step of refinement, α += A⁻¹ Pᵀ W (Z - P α): Pᵀ W Z and Pᵀ W P α cancel down to
    the residuals where the fit nearly interpolates, so the residual form is the accurate
    one."""
    cdef double delta[KMAX]
    cdef double acc
    cdef const double *bas
    cdef int64_t i
    cdef int j
    for j in range(k):
        delta[j] = 0.0
    for i in range(n):
        bas = sc.bas + 6 * k * i
        acc = sc.w[3 * i] * (sc.z[i] - dot(bas, alpha, k))
        for j in range(k):
            delta[j] += acc * bas[j]
    cholesky_solve(A, k, dchol, delta)
    for j in range(k):
        alpha[j] += delta[j]


cdef inline void cholesky_solve3(const double *r, int n, const double *d, double *x,
                                 int64_t stride) noexcept nogil:
    """`cholesky_solve` of three right-hand sides x, x + stride, x + 2 stride at once (each
    bitwise the one-at-a-time solve's: the same operations in the same order; the node's
    three Δ = A⁻¹ β share the loops)."""
    cdef int i, j
    cdef double a0, a1, a2, rk
    cdef double *y = x + stride
    cdef double *z = x + 2 * stride
    for i in range(n):
        a0 = x[i]
        a1 = y[i]
        a2 = z[i]
        for j in range(i):
            rk = r[j * n + i]
            a0 -= rk * x[j]
            a1 -= rk * y[j]
            a2 -= rk * z[j]
        x[i] = a0 * d[i]
        y[i] = a1 * d[i]
        z[i] = a2 * d[i]
    for i in range(n - 1, -1, -1):
        a0 = x[i]
        a1 = y[i]
        a2 = z[i]
        for j in range(i + 1, n):
            rk = r[i * n + j]
            a0 -= rk * x[j]
            a1 -= rk * y[j]
            a2 -= rk * z[j]
        x[i] = a0 * d[i]
        y[i] = a1 * d[i]
        z[i] = a2 * d[i]


cdef inline double kdot(const double *a, const double *b, int k) noexcept nogil:
    """`dot` (summed from 0 in the same order, bitwise), unrolled for the quadratic basis's
    k = 6 (the per-node loops' hundreds of short dots)."""
    if k == 6:
        return (0.0 + a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4]
                + a[5] * b[5])
    return dot(a, b, k)


cdef inline void gap_derivatives(double s1, double s2, double e3, const double *fd, double R,
                                 bint second, double *gap, double *gG,
                                 double *hG) noexcept nogil:
    """G = num ℓ, num = σ1 f,1 + σ2 f,2 + X3^c - f, ℓ = (1 + f,1² + f,2²)^-½ [29], [32] at
    σ = (s1, s2), e3 = X3^c - f, fd = (f, f,1, f,2, ...): g = R G into gap, its gradient
    over y = (σ1, σ2, X3^c, f, f,1, f,2) into gG and (`second`) its Hessian into hG."""
    cdef double f1 = fd[1], f2 = fd[2], num, ell, ell3, ell5
    cdef double dnum[6]
    cdef double dell[6]
    cdef int j, v
    ell = 1.0 / sqrt(1.0 + f1 * f1 + f2 * f2)
    ell3 = ell * ell * ell
    ell5 = ell3 * ell * ell
    num = s1 * f1 + s2 * f2 + e3
    gap[0] = R * num * ell
    dnum[0] = f1
    dnum[1] = f2
    dnum[2] = 1.0
    dnum[3] = -1.0
    dnum[4] = s1
    dnum[5] = s2
    for j in range(6):
        dell[j] = 0.0
    dell[4] = -f1 * ell3
    dell[5] = -f2 * ell3
    for j in range(6):
        gG[j] = ell * dnum[j] + num * dell[j]
    if second:
        for j in range(6):
            for v in range(6):
                hG[6 * j + v] = dnum[j] * dell[v] + dell[j] * dnum[v]
        hG[6 * 0 + 4] += ell
        hG[6 * 4 + 0] += ell
        hG[6 * 1 + 5] += ell
        hG[6 * 5 + 1] += ell
        hG[6 * 4 + 4] += num * (3.0 * f1 * f1 * ell5 - ell3)
        hG[6 * 5 + 5] += num * (3.0 * f2 * f2 * ell5 - ell3)
        hG[6 * 4 + 5] += num * 3.0 * f1 * f2 * ell5
        hG[6 * 5 + 4] += num * 3.0 * f1 * f2 * ell5


cdef inline void adjoints(const double *A, const double *dchol, int k, const double *Q,
                          const double *gG, bint second, double *rho, double *lam,
                          double *mu) noexcept nogil:
    """The adjoints: ρ_j = A⁻¹ q_j (j: f, f,1, f,2), λ = Σ_j G_{,f_j} ρ_j and (`second`)
    μ_k = A⁻¹ Σ_j G_{,f_j} ∂q_j/∂σ_k, from q (Q: p, p,s, p,t, p,ss, p,st, p,tt at σ)."""
    cdef int j, v
    for j in range(3):
        for v in range(k):
            rho[j * k + v] = Q[j * k + v]
        cholesky_solve(A, k, dchol, rho + j * k)
    for v in range(k):
        lam[v] = gG[3] * rho[v] + gG[4] * rho[k + v] + gG[5] * rho[2 * k + v]
    if second:
        for v in range(k):  # ∂q_j/∂σ1: p,s, p,ss, p,st; ∂q_j/∂σ2: p,t, p,st, p,tt
            mu[v] = gG[3] * Q[k + v] + gG[4] * Q[3 * k + v] + gG[5] * Q[4 * k + v]
            mu[k + v] = gG[3] * Q[2 * k + v] + gG[4] * Q[4 * k + v] + gG[5] * Q[5 * k + v]
        cholesky_solve(A, k, dchol, mu)
        cholesky_solve(A, k, dchol, mu + k)


cdef inline void gradient(Scratch *sc, int64_t n, int64_t L, const double *axes,
                          const double *gG, bint second, double *N) noexcept nogil:
    """The contactor's rows of sc.X (X1^c, X2^c enter through every s_i, t_i; X3^c through
    e_X3 only), the chain rule through X = axes (x - o) / R block by block, and 𝒩 into N."""
    cdef int64_t i, col, m = 3 * (n + 1)
    cdef int a, r
    cdef double *x
    for i in range(n):
        for a in range(2):
            x = sc.X + (3 + 3 * i + a) * L
            for r in range(L if second else 4):
                sc.X[a * L + r] -= x[r]
    sc.X[2 * L] = 1.0
    # chain rule through X = axes (x - o) / R, block by block
    for i in range(n + 1):
        rotate_block(sc.X + 3 * i * L, axes, L, L if second else 4)
    # 𝒩 = R ∂G/∂u = axesᵀ ∂G/∂X per block; ∂G/∂w = Σ_r gG[2 + r] V_r (r < 4)
    for col in range(m):
        x = sc.X + col * L
        N[col] = gG[2] * x[0] + gG[3] * x[1] + gG[4] * x[2] + gG[5] * x[3]


cdef inline bint second_order_form(const double *fd, double e3, const double *hG,
                                   double *S) noexcept nogil:
    """S: the Hessian of G in (X3^c, f, f,1, f,2), minus the implicit-function term
    G_{,wσ} D_{,σσ}⁻¹ D_{,σw} [30] (fd = f, f,1, f,2, f,11, f,12, f,22); False where D_{,σσ}
    is singular."""
    cdef double f1 = fd[1], f2 = fd[2], f11 = fd[3], f12 = fd[4], f22 = fd[5], det, acc
    cdef double Cg[2 * NV]           # ∂²G/∂σ_k∂w = Cg[k] V
    cdef double Cd[2 * NV]           # ∂²D/∂σ_k∂w = Cd[k] V
    cdef double h[6]
    cdef double Dss[4]
    cdef double Dinv[4]
    cdef int j, r, a, b, kk
    Dss[0] = 1.0 + f1 * f1 - e3 * f11
    Dss[1] = f1 * f2 - e3 * f12
    Dss[2] = Dss[1]
    Dss[3] = 1.0 + f2 * f2 - e3 * f22
    det = Dss[0] * Dss[3] - Dss[1] * Dss[2]
    if not (det != 0.0):
        return False
    Dinv[0] = Dss[3] / det
    Dinv[1] = -Dss[1] / det
    Dinv[2] = -Dss[2] / det
    Dinv[3] = Dss[0] / det
    for kk in range(2):
        # Y_σk = e_σk + ∂(f, f,1, f,2)/∂σk on the y slots; h = ∇²G Y_σk
        for j in range(6):
            h[j] = hG[6 * j + kk]
            if kk == 0:
                h[j] += hG[6 * j + 3] * f1 + hG[6 * j + 4] * f11 + hG[6 * j + 5] * f12
            else:
                h[j] += hG[6 * j + 3] * f2 + hG[6 * j + 4] * f12 + hG[6 * j + 5] * f22
        for r in range(4):
            Cg[kk * NV + r] = h[2 + r]
        Cg[kk * NV + 4] = 1.0 if kk == 0 else 0.0
        Cg[kk * NV + 5] = 1.0 if kk == 1 else 0.0
        for r in range(NV):
            Cd[kk * NV + r] = 0.0
        Cd[kk * NV + 0] = -(f1 if kk == 0 else f2)
        Cd[kk * NV + 1] = f1 if kk == 0 else f2
        Cd[kk * NV + 2 + kk] = -e3
    for r in range(NV):
        for j in range(NV):
            S[r * NV + j] = hG[6 * (2 + r) + 2 + j] if (r < 4 and j < 4) else 0.0
    for r in range(NV):
        for j in range(NV):
            acc = 0.0
            for a in range(2):
                for b in range(2):
                    acc += (Cg[a * NV + r] * Dinv[2 * a + b] * Cd[b * NV + j]
                            + Cg[a * NV + j] * Dinv[2 * a + b] * Cd[b * NV + r])
            S[r * NV + j] -= 0.5 * acc
    return True


cdef inline void hessian(const Scratch *sc, const double *S, int k, int64_t n, int64_t L,
                         const double *axes, double inv_r, double *M, int64_t ldm,
                         bint reference) noexcept nogil:
    """ℳ into M (row stride ldm, the leading 3(n+1) square) from the rows X (sc.X), S and the
    node-diagonal blocks (sc.E). `reference`: the kernel before issue 33's (rank-one row
    updates, the rotations as quadruple sums), kept to check this one against."""
    cdef int64_t i, col, c2, m = 3 * (n + 1)
    cdef int j, v, r
    cdef double ecc[9]
    cdef double ec[9]
    cdef const double *x
    cdef double *y
    cdef double *row
    cdef const double *e
    # Y = (S V, -Δ, -Γ), stored by rows (L x m): ℳ_ab = X_a · Y_b + E
    # (Vᵀ S V - Γᵀ Δ - Δᵀ Γ + node blocks), the product in register tiles (ds_rank_upper)
    for col in range(m):
        x = sc.X + col * L
        y = sc.Y + col
        for r in range(NV):
            y[r * m] = dot(S + r * NV, x, NV)
        for v in range(k):
            y[(NV + v) * m] = -x[NV + k + v]
            y[(NV + k + v) * m] = -x[NV + v]
    if reference:
        for col in range(m):
            x = sc.X + col * L
            row = M + col * ldm
            for c2 in range(col, m):
                row[c2] = 0.0
            for r in range(L):
                ds_axpy(row + col, sc.Y + r * m + col, x[r], m - col)
    else:
        ds_rank_upper(M, ldm, sc.X, sc.Y, L, m)
    # node-diagonal blocks: (x_i, x_i) E_i; (x^c, x_i) Tᵀ E_i; (x^c, x^c) Σ Tᵀ E_i T, with
    # T = ∂(s_i, t_i, Z_i)/∂X^c = diag(-1, -1, 0)
    for j in range(9):
        ecc[j] = 0.0
    for i in range(n):
        e = sc.E + 9 * i
        for j in range(9):
            ec[j] = -e[j] if j < 6 else 0.0
        if reference:
            add_rotated_reference(M, ldm, 3 + 3 * i, 3 + 3 * i, e, axes, True)
            add_rotated_reference(M, ldm, 0, 3 + 3 * i, ec, axes, False)
        else:
            add_rotated(M, ldm, 3 + 3 * i, 3 + 3 * i, e, axes, True)
            add_rotated(M, ldm, 0, 3 + 3 * i, ec, axes, False)
        ecc[0] += e[0]
        ecc[1] += e[1]
        ecc[3] += e[3]
        ecc[4] += e[4]
    if reference:
        add_rotated_reference(M, ldm, 0, 0, ecc, axes, True)
    else:
        add_rotated(M, ldm, 0, 0, ecc, axes, True)
    # ℳ = R (axes/R)ᵀ ∂²G/∂X² (axes/R): the 1/R; symmetric by construction
    for col in range(m):
        for c2 in range(col, m):
            M[col * ldm + c2] *= inv_r
            M[c2 * ldm + col] = M[col * ldm + c2]


cdef bint element_one(const Params *pa, const double *nodes, const double *xc,
                      const double *origin, const double *axes, double R, const double *xd,
                      const int64_t *idx, int64_t n, bint second, Scratch *sc,
                      double *gap, double *N, double *M, int64_t ldm,
                      bint reference=False) noexcept nogil:
    """g, 𝒩 (into N[:3(n+1)]) and ℳ (into M, row stride ldm, the leading 3(n+1) square) of
    one contactor with support nodes idx[:n] (all of positive weight); False where the fit or
    the proximal point's system is singular (the caller fills NaN). `reference`: ℳ by the
    reference kernel (`hessian`)."""
    cdef int k = pa.k, j, v, a
    cdef int64_t i, L = NV + 2 * k, col
    cdef double inv_r = 1.0 / R
    cdef double c[3]
    cdef double xbar[3]
    cdef double A[KMAX * KMAX]
    cdef double dchol[KMAX]          # 1 / the diagonal of A's Cholesky factor
    cdef double alpha[KMAX]
    cdef double Q[6 * KMAX]          # p, p,s, p,t, p,ss, p,st, p,tt at σ
    cdef double fd[6]                # f, f,1, f,2, f,11, f,12, f,22 at σ
    cdef double rho[3 * KMAX]        # A⁻¹ q_j, j: f, f,1, f,2
    cdef double lam[KMAX]            # λ = A⁻¹ Σ_j G_{,f_j} q_j
    cdef double mu[2 * KMAX]         # μ_k = A⁻¹ Σ_j G_{,f_j} ∂q_j/∂σ_k
    cdef double beta[3 * KMAX]       # ∂b - ∂A α for the node's s, t, Z
    cdef double gam[2 * KMAX]
    cdef double gG[6]                # ∇G over y = (σ1, σ2, X3^c, f, f,1, f,2)
    cdef double hG[36]               # ∇²G over y
    cdef double S[NV * NV]
    cdef double s1, s2, e3
    cdef double si, ti, wi, w1, w2, ws, wt, wss, wst, wtt, ri, es, et, ess, est, ett
    cdef double lp, lps, lpt, lpss, lpst, lptt, lm, lms, lmt, lmss, lmst, lmtt
    cdef double *bas
    cdef double *x
    cdef double *e

    # local coordinates of the contactor, the proximal point and the support [§3]
    to_local(xc, origin, axes, inv_r, c)
    to_local(xd, origin, axes, inv_r, xbar)
    s1 = xbar[0] - c[0]
    s2 = xbar[1] - c[1]
    # A = Pᵀ W P, b = Pᵀ W Z [17] (b into alpha), the fit α, refined
    moments(pa, nodes, c, origin, axes, inv_r, idx, n, sc, A, alpha)
    if not cholesky(A, k, dchol):
        return False
    cholesky_solve(A, k, dchol, alpha)
    refine(sc, k, n, A, dchol, alpha)

    # the local approximation at the proximal point [13], [28]
    basis_derivatives(k, pa.ea, pa.eb, s1, s2, Q)
    for j in range(6):
        fd[j] = dot(Q + j * k, alpha, k)
    e3 = c[2] - fd[0]

    gap_derivatives(s1, s2, e3, fd, R, second, gap, gG, hG)  # [32]
    adjoints(A, dchol, k, Q, gG, second, rho, lam, mu)

    # per node: β, the rows V, Γ, Δ = A⁻¹ β, and the node-diagonal block E
    for col in range(3 * L):  # the contactor's rows accumulate -Σ over the nodes
        sc.X[col] = 0.0
    for i in range(n):
        si = sc.s[i]
        ti = sc.t[i]
        wi = sc.w[3 * i]
        w1 = sc.w[3 * i + 1]
        w2 = sc.w[3 * i + 2]
        ws = 2.0 * si * w1
        wt = 2.0 * ti * w1
        bas = sc.bas + 6 * k * i
        ri = sc.z[i] - kdot(bas, alpha, k)      # residual Z_i - p_iᵀα
        es = -kdot(bas + k, alpha, k)           # ∂(Z - pᵀα)/∂s at fixed α
        et = -kdot(bas + 2 * k, alpha, k)
        for v in range(k):
            # m = w p: m,s = w,s p + w p,s; β_s = m,s r + w p e,s; β_Z = w p
            beta[v] = (ws * bas[v] + wi * bas[k + v]) * ri + wi * bas[v] * es
            beta[k + v] = (wt * bas[v] + wi * bas[2 * k + v]) * ri + wi * bas[v] * et
            beta[2 * k + v] = wi * bas[v]
        for a in range(3):
            x = sc.X + (3 + 3 * i + a) * L
            x[0] = 0.0
            x[1] = kdot(rho, beta + a * k, k)
            x[2] = kdot(rho + k, beta + a * k, k)
            x[3] = kdot(rho + 2 * k, beta + a * k, k)
            if not second:
                continue
            x[4] = kdot(mu, beta + a * k, k)
            x[5] = kdot(mu + k, beta + a * k, k)
        if not second:
            continue
        lp = kdot(lam, bas, k)
        lps = kdot(lam, bas + k, k)
        lpt = kdot(lam, bas + 2 * k, k)
        lpss = kdot(lam, bas + 3 * k, k)
        lpst = kdot(lam, bas + 4 * k, k)
        lptt = kdot(lam, bas + 5 * k, k)
        wss = 2.0 * w1 + 4.0 * si * si * w2
        wst = 4.0 * si * ti * w2
        wtt = 2.0 * w1 + 4.0 * ti * ti * w2
        lm = wi * lp
        lms = ws * lp + wi * lps
        lmt = wt * lp + wi * lpt
        lmss = wss * lp + 2.0 * ws * lps + wi * lpss
        lmst = wst * lp + ws * lpt + wt * lps + wi * lpst
        lmtt = wtt * lp + 2.0 * wt * lpt + wi * lptt
        ess = -kdot(bas + 3 * k, alpha, k)
        est = -kdot(bas + 4 * k, alpha, k)
        ett = -kdot(bas + 5 * k, alpha, k)
        # λᵀ ∂²(m (Z - pᵀα)) at fixed α, over (s, t, Z)
        e = sc.E + 9 * i
        e[0] = lmss * ri + 2.0 * lms * es + lm * ess
        e[1] = lmst * ri + lms * et + lmt * es + lm * est
        e[4] = lmtt * ri + 2.0 * lmt * et + lm * ett
        e[2] = lms
        e[5] = lmt
        e[8] = 0.0
        e[3] = e[1]
        e[6] = e[2]
        e[7] = e[5]
        # γ_a = ∂A_aᵀ λ = (λᵀ m,a) p + w (λᵀ p) p,a (a = s, t; A does not depend on Z)
        for v in range(k):
            gam[v] = lms * bas[v] + wi * lp * bas[k + v]
            gam[k + v] = lmt * bas[v] + wi * lp * bas[2 * k + v]
        for a in range(3):
            x = sc.X + (3 + 3 * i + a) * L
            for v in range(k):
                x[NV + v] = gam[a * k + v] if a < 2 else 0.0
                x[NV + k + v] = beta[a * k + v]
        cholesky_solve3(A, k, dchol, sc.X + (3 + 3 * i) * L + NV + k, L)
    gradient(sc, n, L, axes, gG, second, N)
    if not second:
        return True

    # S: the Hessian of G in (X3^c, f, f,1, f,2), minus G_{,wσ} D_{,σσ}⁻¹ D_{,σw} [30]
    if not second_order_form(fd, e3, hG, S):
        return False
    hessian(sc, S, k, n, L, axes, inv_r, M, ldm, reference)
    return True


# --------------------------------------------------------------------------------------------
# the calls
# --------------------------------------------------------------------------------------------

cdef int64_t support_one(const Params *pa, const double[:, ::1] nodes, const double *xc,
                         const double *origin, const double *axes, double R,
                         const int64_t *index, int64_t K, int64_t *kept) noexcept nogil:
    """kept[:count] = the nodes of index[:K] with positive weight, -1 after; returns count."""
    cdef int64_t j, node, cnt = 0
    cdef double inv_r = 1.0 / R
    cdef double c[3]
    cdef double X[3]
    to_local(xc, origin, axes, inv_r, c)
    for j in range(K):
        node = index[j]
        if node < 0:
            continue
        to_local(&nodes[node, 0], origin, axes, inv_r, X)
        if weight_value(pa.wp.kind, (X[0] - c[0]) * (X[0] - c[0])
                        + (X[1] - c[1]) * (X[1] - c[1]), &pa.wp) > 0.0:
            kept[cnt] = node
            cnt += 1
    for j in range(cnt, K):
        kept[j] = -1
    return cnt


def supports(const double[:, ::1] nodes, const double[:, ::1] contactors,
             const double[:, ::1] origin, const double[:, :, ::1] axes,
             const double[::1] radius, const int64_t[:, ::1] index, basis, str weight,
             int64_t[:, ::1] kept, int64_t[::1] count, int threads=0):
    """The support nodes of positive weight (those that move the fit) of each contactor:
    kept[i, :count[i]] (in index order, -1 after). `threads`: OpenMP threads of the loop (0:
    `threads.threads_for`'s; 1: a plain loop, no parallel region)."""
    cdef Params pa = _params(basis, weight)
    cdef Py_ssize_t e = contactors.shape[0], i
    cdef int64_t j, K = index.shape[1], nn = nodes.shape[0], node
    if not (origin.shape[0] == axes.shape[0] == radius.shape[0] == index.shape[0] == e
            and kept.shape[0] == count.shape[0] == e and kept.shape[1] == K):
        raise ValueError("supports: inconsistent row counts")
    for i in range(e):
        for j in range(K):
            node = index[i, j]
            if node >= nn:
                raise ValueError(f"support index {node} beyond the {nn} target nodes")
    if e == 0 or K == 0:
        for i in range(e):
            count[i] = 0
        return
    if threads <= 0:
        threads = threads_for(e, "supports")
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            for i in range(e):
                count[i] = support_one(&pa, nodes, &contactors[i, 0], &origin[i, 0],
                                       &axes[i, 0, 0], radius[i], &index[i, 0], K, &kept[i, 0])
    else:
        for i in prange(e, nogil=True, schedule="static", num_threads=threads):
            count[i] = support_one(&pa, nodes, &contactors[i, 0], &origin[i, 0],
                                   &axes[i, 0, 0], radius[i], &index[i, 0], K, &kept[i, 0])


cdef struct ElementIO:
    # the arrays of `elements` (C-contiguous), as raw pointers
    const double *nodes
    const double *contactors
    const double *origin
    const double *axes
    const double *radius
    const double *proximal
    const int64_t *kept          # (e, K)
    const int64_t *count
    int64_t K
    double *gap
    double *N                    # (e, 3(K+1))
    double *M                    # (e, 3(K+1), 3(K+1)) or NULL
    bint reference               # ℳ by the reference kernel


cdef inline void element_row(const Params *pa, const ElementIO *io, Py_ssize_t i,
                             Scratch *sc) noexcept nogil:
    """`elements`' work for contactor i, the same from the serial loop and the parallel
    one."""
    cdef int64_t ldm = 3 * (io.K + 1), j, v
    cdef int64_t n = io.count[i]
    cdef int64_t used = 3 * (n + 1)
    cdef bint second = io.M != NULL
    cdef double *Ni = io.N + i * ldm
    cdef double *Mi = io.M + i * ldm * ldm if second else NULL
    cdef bint ok = n >= pa.k and element_one(pa, io.nodes, io.contactors + 3 * i,
                                             io.origin + 3 * i, io.axes + 9 * i, io.radius[i],
                                             io.proximal + 3 * i, io.kept + i * io.K, n,
                                             second, sc, &io.gap[i], Ni, Mi, ldm,
                                             io.reference)
    if not ok:
        io.gap[i] = NAN
        for j in range(used):
            Ni[j] = NAN
    for j in range(used, ldm):
        Ni[j] = 0.0
    if second:
        for j in range(ldm):
            if j < used and not ok:
                for v in range(used):
                    Mi[j * ldm + v] = NAN
            for v in range(used if j < used else 0, ldm):
                Mi[j * ldm + v] = 0.0


def elements(const double[:, ::1] nodes, const double[:, ::1] contactors,
             const double[:, ::1] origin, const double[:, :, ::1] axes,
             const double[::1] radius, const double[:, ::1] proximal,
             const int64_t[:, ::1] kept, const int64_t[::1] count, basis, str weight,
             double[::1] gap, double[:, ::1] N, double[:, :, ::1] M, int threads=0,
             bint reference=False):
    """g, 𝒩 and (when M has rows) ℳ of each contactor, u = [x^c, x^kept[i, 0], ...]; rows
    whose fit or proximal point is singular get NaN (on their 3(n+1) block; padding 0).
    `threads`: as `supports`'. `reference`: ℳ by the kernel before issue 33's (rank-one
    updates, `hessian`), the slow obvious one tests check the fast one against."""
    cdef Params pa = _params(basis, weight)
    cdef Py_ssize_t e = contactors.shape[0], i
    cdef int64_t K = kept.shape[1], ldm = 3 * (K + 1)
    cdef bint second = M.shape[0] > 0
    cdef Scratch *sc
    cdef int failed = 0
    cdef int *failedp = &failed
    if not (origin.shape[0] == axes.shape[0] == radius.shape[0] == proximal.shape[0] == e
            and kept.shape[0] == count.shape[0] == gap.shape[0] == N.shape[0] == e):
        raise ValueError("elements: inconsistent row counts")
    if N.shape[1] != ldm or (second and (M.shape[0] != e or M.shape[1] != ldm
                                         or M.shape[2] != ldm)):
        raise ValueError("elements: N must be (e, 3(K+1)) and M (e, 3(K+1), 3(K+1)) or empty")
    if e == 0:
        return
    cdef ElementIO io
    io.nodes, io.contactors, io.origin = &nodes[0, 0], &contactors[0, 0], &origin[0, 0]
    io.axes, io.radius, io.proximal = &axes[0, 0, 0], &radius[0], &proximal[0, 0]
    io.kept, io.count, io.K = &kept[0, 0] if K > 0 else NULL, &count[0], K
    io.gap, io.N = &gap[0], &N[0, 0]
    io.M = &M[0, 0, 0] if second else NULL
    io.reference = reference
    cdef int chunk
    if threads <= 0:
        threads = threads_for(e, "elements")
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            sc = scratch_new(K, pa.k)
            if sc != NULL:
                for i in range(e):
                    element_row(&pa, &io, i, sc)
                scratch_free(sc)
            else:
                failed = 1
    else:
        chunk = chunk_size(e, threads, 16)
        with nogil, parallel(num_threads=threads):
            sc = scratch_new(K, pa.k)
            if sc == NULL:
                failedp[0] = 1
            for i in prange(e, schedule="dynamic", chunksize=chunk):
                if sc != NULL:
                    element_row(&pa, &io, i, sc)
            scratch_free(sc)
    if failed:
        raise MemoryError("no memory for the contact element's scratch")


# --------------------------------------------------------------------------------------------
# The node-to-facet element [§2]: gap, 𝒩 = ∂g/∂u [7], ℳ = ∂²g/∂u² [9]-[10]
# --------------------------------------------------------------------------------------------
#
# u = [x^c, x_0, ..., x_{p-1}] (p = 3 corners of a linear triangle, 4 of a bilinear quad);
# x^m = Σ_j N_j(ξ) x_j [1], d = x^c − x^m = Σ_k c_k u_k with c = (1, −N_0, ..., −N_{p-1}), and
# t_α = Σ_j N_j,α x_j = −Σ_k c_k,α u_k (c_0,α = 0). ξ is stationary for D = ½ d·d [1]: free
# inside the facet (θ = ξ), along an edge (θ one parameter, ξ = ξ0 + E θ), none at a vertex.
#
# Inside, g = s d·ν [2], ν = m/|m|, m = t_1 × t_2 (s = ±1, the orientation). At the closest
# point Πd = 0 (Π = I − ννᵀ: d is along ν), so, with A_k = c_k,1 [t_2]× − c_k,2 [t_1]× = ∂m/∂u_k
# and B_k = Π A_k / |m| = ∂ν/∂u_k, ĝ = d·ν:
#   𝒩_k = s c_k ν
#   ∂²G/∂u_k∂u_l = c_k B_l + c_l B_kᵀ − ĝ B_kᵀ B_l              (d·∂²ν = −ĝ ∂νᵀ∂ν)
#   ∂²G/∂ξ_α∂u_k = c_k,α ν + c_k ν_α − A_kᵀ t_α/|m| − ĝ A_kᵀ ν_α/|m|   (ν_α = ∂ν/∂ξ_α)
#   D_αβ = t_α·t_β − d·t_α,β,   D_αu_k = −c_k t_α + c_k,α d
# and ℳ = s (∂²G/∂u² − ∂²G/∂u∂ξ D_ξξ⁻¹ D_ξu) (implicit function theorem). A bilinear quad's
# only second derivative is its twist w = Σ_j N_j,12 x_j = t_1,2 (∂m/∂ξ_1 = t_1 × w,
# ∂m/∂ξ_2 = w × t_2); a triangle has none.
#
# On an edge or at a vertex, g = side |d| (the signed distance to x^m): with n = d/|d|,
# P = I − nnᵀ, 𝒩_k = side c_k n, ∂²G/∂u_k∂u_l = side c_k c_l P/|d|; on an edge of direction E
# (b_k = c_k,α E_α, t_E = E_α t_α: ∂d/∂θ = −t_E, and ∂²d/∂θ² = 0 on every edge),
# ∂²G/∂θ∂u_k = side (b_k n − c_k P t_E/|d|), D_θθ = t_E·t_E, D_θu_k = −c_k t_E + b_k d.

cdef inline void cross3(const double *a, const double *b, double *out) noexcept nogil:
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


cdef inline void skew_add(double *A, double coef, const double *a) noexcept nogil:
    """A += coef [a]× (3x3, row-major; [a]× v = a × v)."""
    A[1] -= coef * a[2]
    A[2] += coef * a[1]
    A[3] += coef * a[2]
    A[5] -= coef * a[0]
    A[6] -= coef * a[1]
    A[7] += coef * a[0]


cdef inline void facet_shape(const double *X, int p, const double *xc, double a, double b,
                             double *c, double *ca, double *d, double *t,
                             double *w) noexcept nogil:
    """The facet's shape functions [1] at (a, b): c (the gap's weights of x^c and the corners,
    1 and -N_j), ca (c_k,α: ca[2k + α]), d = x^c - x(a, b), the tangents t_1, t_2 (t[:3],
    t[3:]) and w = ∂²x/∂a∂b (zero on a triangle)."""
    cdef double Nj[4]
    cdef double dN[8]
    cdef double q[4]
    cdef int i, j
    if p == 3:
        Nj[0] = 1.0 - a - b
        Nj[1] = a
        Nj[2] = b
        dN[0] = -1.0
        dN[1] = -1.0
        dN[2] = 1.0
        dN[3] = 0.0
        dN[4] = 0.0
        dN[5] = 1.0
        for j in range(4):
            q[j] = 0.0
    else:
        Nj[0] = (1.0 - a) * (1.0 - b)
        Nj[1] = a * (1.0 - b)
        Nj[2] = a * b
        Nj[3] = (1.0 - a) * b
        dN[0] = -(1.0 - b)
        dN[1] = -(1.0 - a)
        dN[2] = 1.0 - b
        dN[3] = -a
        dN[4] = b
        dN[5] = a
        dN[6] = -b
        dN[7] = 1.0 - a
        q[0] = 1.0
        q[1] = -1.0
        q[2] = 1.0
        q[3] = -1.0
    c[0] = 1.0
    ca[0] = 0.0
    ca[1] = 0.0
    for j in range(p):
        c[j + 1] = -Nj[j]
        ca[2 * j + 2] = -dN[2 * j]
        ca[2 * j + 3] = -dN[2 * j + 1]
    for i in range(3):
        d[i] = xc[i]
        t[i] = 0.0
        t[3 + i] = 0.0
        w[i] = 0.0
        for j in range(p):
            d[i] -= Nj[j] * X[3 * j + i]
            t[i] += dN[2 * j] * X[3 * j + i]
            t[3 + i] += dN[2 * j + 1] * X[3 * j + i]
            w[i] += q[j] * X[3 * j + i]


cdef inline bint facet_boundary(int p, const double *c, const double *ca, const double *d,
                                const double *t, const double *E, bint vertex, double side,
                                bint second, double *gap, double *N, double *M,
                                int W) noexcept nogil:
    """The element of a closest point on an edge of direction E (ξ) or at a vertex: g = side
    |d|, 𝒩 and (`second`) ℳ (module comment above); False where |d| or the edge's tangent is
    zero."""
    cdef double Gx[15]            # ∂²G/∂θ∂u_k
    cdef double Tu[15]            # ∂θ/∂u_k
    cdef double tE[3]
    cdef double rho, s, dot_, v, bk
    cdef int k, k2, i, j
    rho = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    if not rho > 0.0:
        return False
    gap[0] = side * rho
    for k in range(p + 1):
        for i in range(3):
            N[3 * k + i] = side * c[k] * d[i] / rho
    if not second:
        return True
    for k in range(p + 1):
        for k2 in range(p + 1):
            for i in range(3):
                for j in range(3):
                    v = (1.0 if i == j else 0.0) - d[i] * d[j] / (rho * rho)
                    M[(3 * k + i) * W + 3 * k2 + j] = side * c[k] * c[k2] * v / rho
    if not vertex:
        for i in range(3):
            tE[i] = E[0] * t[i] + E[1] * t[3 + i]
        s = tE[0] * tE[0] + tE[1] * tE[1] + tE[2] * tE[2]
        if not s > 0.0:
            return False
        dot_ = (d[0] * tE[0] + d[1] * tE[1] + d[2] * tE[2]) / rho  # n·t_E
        for k in range(p + 1):
            bk = E[0] * ca[2 * k] + E[1] * ca[2 * k + 1]
            for i in range(3):  # side (b_k n − c_k P t_E/|d|), P t_E = t_E − (n·t_E) n
                v = tE[i] - dot_ * d[i] / rho
                Gx[3 * k + i] = side * (bk * d[i] - c[k] * v) / rho
                Tu[3 * k + i] = (c[k] * tE[i] - bk * d[i]) / s  # −D_θθ⁻¹ D_θu_k
        for k in range(p + 1):
            for k2 in range(p + 1):
                for i in range(3):
                    for j in range(3):
                        M[(3 * k + i) * W + 3 * k2 + j] += Gx[3 * k + i] * Tu[3 * k2 + j]
    return True


cdef bint facet_one(const double *X, int p, const double *xc, double a, double b,
                    double side, double sgn, double eps, bint second, double *gap, double *N,
                    double *M, int W) noexcept nogil:
    """The node-to-facet element of one contactor (module comment above): g, 𝒩 (W) and, when
    `second`, ℳ (W x W, row-major) for corners X (p x 3) and the closest point's facet
    parameters (a, b). Entries past 3(p+1) are left as they are. False: a degenerate facet
    (a zero normal or distance where one is needed)."""
    cdef double c[5]
    cdef double ca[10]            # c_k,α: ca[2k + α]
    cdef double d[3]
    cdef double t[6]              # t_1, t_2
    cdef double w[3]
    cdef double m[3]
    cdef double nu[3]
    cdef double nua[6]            # ν_1, ν_2
    cdef double dm[3]
    cdef double A[45]             # A_k (5 x 3x3)
    cdef double B[45]
    cdef double Gx[30]            # ∂²G/∂θ_α∂u_k: Gx[(2k + α) 3 + i]
    cdef double Tu[30]            # ∂θ_α/∂u_k: Tu[(2k + α) 3 + i]
    cdef double Dx[30]            # D_θαu_k
    cdef double E[2]
    cdef double Dtt[4]
    cdef double inv[4]
    cdef double mu, ghat, det, dot_, v, acc
    cdef int n = 3 * (p + 1), k, k2, i, j, e, al
    cdef bint interior, vertex
    facet_shape(X, p, xc, a, b, c, ca, d, t, w)
    # where the closest point lies (facet.surface.free_parameters)
    E[0] = 0.0
    E[1] = 0.0
    interior = False
    vertex = False
    if p == 3 and a > eps and b > eps and a + b < 1.0 - eps:
        interior = True
    elif p == 3 and a + b >= 1.0 - eps and a > eps and b > eps:
        E[0] = 1.0
        E[1] = -1.0
    elif eps < a < 1.0 - eps and eps < b < 1.0 - eps:
        interior = True
    elif eps < a < 1.0 - eps:
        E[0] = 1.0
    elif eps < b < 1.0 - eps:
        E[1] = 1.0
    else:
        vertex = True
    if interior:
        cross3(t, t + 3, m)
        mu = sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
        if not mu > 0.0:
            return False
        ghat = 0.0
        for i in range(3):
            nu[i] = m[i] / mu
            ghat += d[i] * nu[i]
        gap[0] = sgn * ghat
        for k in range(p + 1):
            for i in range(3):
                N[3 * k + i] = sgn * c[k] * nu[i]
        if not second:
            return True
        # ν_α = Π ∂m/∂ξ_α / |m|
        for al in range(2):
            if al == 0:
                cross3(t, w, dm)
            else:
                cross3(w, t + 3, dm)
            dot_ = nu[0] * dm[0] + nu[1] * dm[1] + nu[2] * dm[2]
            for i in range(3):
                nua[3 * al + i] = (dm[i] - dot_ * nu[i]) / mu
        # A_k, B_k = Π A_k / |m|
        for k in range(p + 1):
            for e in range(9):
                A[9 * k + e] = 0.0
            skew_add(A + 9 * k, ca[2 * k], t + 3)
            skew_add(A + 9 * k, -ca[2 * k + 1], t)
            for j in range(3):
                dot_ = 0.0
                for i in range(3):
                    dot_ += nu[i] * A[9 * k + 3 * i + j]
                for i in range(3):
                    B[9 * k + 3 * i + j] = (A[9 * k + 3 * i + j] - nu[i] * dot_) / mu
        # ∂²G/∂ξ_α∂u_k and D_ξαu_k
        for k in range(p + 1):
            for al in range(2):
                for i in range(3):
                    acc = ca[2 * k + al] * nu[i] + c[k] * nua[3 * al + i]
                    for j in range(3):  # (A_kᵀ)_ij = A_k[j, i]
                        acc -= A[9 * k + 3 * j + i] * (t[3 * al + j] + ghat * nua[3 * al + j]) / mu
                    Gx[(2 * k + al) * 3 + i] = acc
                    Dx[(2 * k + al) * 3 + i] = -c[k] * t[3 * al + i] + ca[2 * k + al] * d[i]
        Dtt[0] = t[0] * t[0] + t[1] * t[1] + t[2] * t[2]
        Dtt[3] = t[3] * t[3] + t[4] * t[4] + t[5] * t[5]
        Dtt[1] = t[0] * t[3] + t[1] * t[4] + t[2] * t[5]
        Dtt[1] -= d[0] * w[0] + d[1] * w[1] + d[2] * w[2]
        Dtt[2] = Dtt[1]
        det = Dtt[0] * Dtt[3] - Dtt[1] * Dtt[2]
        if det == 0.0:
            return False
        inv[0] = Dtt[3] / det
        inv[1] = -Dtt[1] / det
        inv[2] = -Dtt[2] / det
        inv[3] = Dtt[0] / det
        for k in range(p + 1):  # ∂ξ/∂u_k = −D_ξξ⁻¹ D_ξu_k
            for al in range(2):
                for i in range(3):
                    Tu[(2 * k + al) * 3 + i] = -(inv[2 * al] * Dx[(2 * k) * 3 + i]
                                                 + inv[2 * al + 1] * Dx[(2 * k + 1) * 3 + i])
        for k in range(p + 1):
            for k2 in range(p + 1):
                for i in range(3):
                    for j in range(3):
                        acc = c[k] * B[9 * k2 + 3 * i + j] + c[k2] * B[9 * k + 3 * j + i]
                        for e in range(3):
                            acc -= ghat * B[9 * k + 3 * e + i] * B[9 * k2 + 3 * e + j]
                        for al in range(2):
                            acc += Gx[(2 * k + al) * 3 + i] * Tu[(2 * k2 + al) * 3 + j]
                        M[(3 * k + i) * W + 3 * k2 + j] = sgn * acc
    elif not facet_boundary(p, c, ca, d, t, E, vertex, side, second, gap, N, M, W):
        return False
    elif not second:
        return True
    # symmetric (the implicit term is, up to round-off)
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (M[i * W + j] + M[j * W + i])
            M[i * W + j] = v
            M[j * W + i] = v
    return True


cdef void facet_row(const double *nodes, const int64_t *corners, const double *xc,
                    const double *xi, double side, double sgn, double eps, bint second,
                    double *gap, double *N, double *M, int W) noexcept nogil:
    """One row of `facet_elements` (NaN where the facet is degenerate)."""
    cdef double X[12]
    cdef int p = 4 if corners[3] >= 0 else 3, j, i
    for j in range(p):
        for i in range(3):
            X[3 * j + i] = nodes[3 * corners[j] + i]
    if not facet_one(X, p, xc, xi[0], xi[1], side, sgn, eps, second, gap, N, M, W):
        gap[0] = NAN
        for i in range(3 * (p + 1)):
            N[i] = NAN


def facet_elements(const double[:, ::1] nodes, const int64_t[:, ::1] corners,
                   const double[:, ::1] contactors, const double[:, ::1] xi,
                   const double[::1] side, double sign, double[::1] gap, double[:, ::1] N,
                   double[:, :, ::1] M, int threads=0):
    """g, 𝒩 and (when M has rows) ℳ of the node-to-facet element of each contactor [§2]:
    u = [x^c, x^corners[i, 0], ...], corners (e, 4) -1 padded (a triangle), the closest
    point's facet parameters ξ (e, 2), `side` ±1 (the contactor's side, for edges and
    vertices), `sign` -1 to reverse the facets. N (e, 15), M (e, 15, 15) or (0, 0, 0): the
    caller zeroes them (the padding stays 0). `threads`: as `elements`'."""
    cdef Py_ssize_t e = contactors.shape[0], r
    cdef bint second = M.shape[0] > 0
    cdef int W = 15
    cdef double eps = tol.EDGE_EPS
    if not (corners.shape[0] == xi.shape[0] == side.shape[0] == gap.shape[0] == N.shape[0]
            == e and corners.shape[1] == 4 and N.shape[1] == W):
        raise ValueError("facet_elements: inconsistent shapes")
    if second and (M.shape[0] != e or M.shape[1] != W or M.shape[2] != W):
        raise ValueError("facet_elements: M must be (e, 15, 15) or empty")
    if e == 0:
        return
    if corners.shape[0] and (np.min(corners[:, :3]) < 0
                             or np.max(corners) >= nodes.shape[0]):
        raise ValueError("facet_elements: corners must index the nodes")
    cdef const double *nd = &nodes[0, 0]
    cdef const int64_t *cr = &corners[0, 0]
    cdef const double *xcp = &contactors[0, 0]
    cdef const double *xip = &xi[0, 0]
    cdef const double *sd = &side[0]
    cdef double *gp = &gap[0]
    cdef double *Np = &N[0, 0]
    cdef double *Mp = &M[0, 0, 0] if second else NULL
    cdef double dummy[1]
    cdef int chunk
    if threads <= 0:
        threads = threads_for(e, "facet_elements")
    chunk = chunk_size(e, threads, 64)
    if threads == 1:  # no parallel region (threads.py)
        with nogil:
            for r in range(e):
                facet_row(nd, cr + 4 * r, xcp + 3 * r, xip + 2 * r, sd[r], sign, eps, second,
                          gp + r, Np + W * r, Mp + W * W * r if second else dummy, W)
    else:
        with nogil, parallel(num_threads=threads):
            for r in prange(e, schedule="dynamic", chunksize=chunk):
                facet_row(nd, cr + 4 * r, xcp + 3 * r, xip + 2 * r, sd[r], sign, eps, second,
                          gp + r, Np + W * r, Mp + W * W * r if second else dummy, W)


# --------------------------------------------------------------------------------------------
# the tangent: each element's ℳ built and summed into CSR at once
# --------------------------------------------------------------------------------------------

def tangent_elements(const double[:, ::1] nodes, const double[:, ::1] contactors,
                     const double[:, ::1] origin, const double[:, :, ::1] axes,
                     const double[::1] radius, const double[:, ::1] proximal,
                     const int64_t[:, ::1] kept, basis, str weight,
                     const int64_t[:, ::1] ids, const double[:, ::1] N,
                     const double[::1] eps, const double[::1] p, const double[:, ::1] lam,
                     const double[:, :, ::1] dT, const int64_t[:, ::1] base,
                     const int64_t[::1] pat_ptr, const int32_t[::1] pat_col,
                     const int32_t[::1] pat_off, const int64_t[:, ::1] id_dofs,
                     double[::1] data):
    """data += each element's tangent block eps 𝒩𝒩ᵀ + p ℳ (+ the multipliers' and
    friction's terms where `lam`, `dT` have rows: `_assembly.add`'s), ℳ built by the same
    kernel as `elements` (bitwise its numbers) into one (3(K+1))² block in cache and added at
    once: no batch of ℳ is written or read again. kept (e, K): the support nodes of positive
    weight of each element (`supports`' answer: the Contact's nodes), ids (e, K+1) their
    node ids in the pattern (`_assembly.pattern`), N (e, 3(K+1)) the elements' 𝒩. Elements
    with eps = p = 0 and no friction add nothing (their block is zero) and are skipped; a
    singular fit or proximal-point system gives NaN in its block, as `elements` does. One
    thread: the sum is order-dependent in round-off, elements are added in row order."""
    cdef Params pa = _params(basis, weight)
    cdef Py_ssize_t e = contactors.shape[0], i
    cdef int64_t K = kept.shape[1], W = 3 * (K + 1), n, j, v, m
    cdef bint multiplied = lam.shape[0] > 0, friction = dT.shape[0] > 0, ok = True, built
    if not (origin.shape[0] == axes.shape[0] == radius.shape[0] == proximal.shape[0] == e
            and kept.shape[0] == ids.shape[0] == N.shape[0] == eps.shape[0] == p.shape[0]
            == e):
        raise ValueError("tangent_elements: inconsistent row counts")
    if ids.shape[1] != K + 1 or N.shape[1] != W:
        raise ValueError("tangent_elements: ids must be (e, K+1) and N (e, 3(K+1))")
    if (multiplied and (lam.shape[0] != e or lam.shape[1] != 3)) or (
            friction and (dT.shape[0] != e or dT.shape[1] != 3 or dT.shape[2] != 3)):
        raise ValueError("tangent_elements: lam must be (e, 3) and dT (e, 3, 3), or empty")
    for i in range(e):
        for j in range(K):
            if kept[i, j] >= nodes.shape[0]:
                raise ValueError(f"support node {kept[i, j]} beyond the {nodes.shape[0]} "
                                 f"target nodes")
    if e == 0:
        return
    cdef Places pl
    pl.base, pl.pat_ptr, pl.pat_col = &base[0, 0], &pat_ptr[0], &pat_col[0]
    pl.pat_off, pl.id_dofs, pl.data = &pat_off[0], &id_dofs[0, 0], &data[0]
    cdef Scratch *sc = scratch_new(K, pa.k)
    cdef BlockScratch *bs = block_scratch_new(K + 1)
    cdef double *Mb = <double *> calloc(W * (W + 1), sizeof(double))  # stale-free padding
    cdef double *Nb = Mb + W * W
    cdef double gap
    cdef const int64_t *idx
    try:
        if sc == NULL or bs == NULL or Mb == NULL:
            raise MemoryError("no memory for the contact tangent's scratch")
        with nogil:
            for i in range(e):
                if eps[i] == 0.0 and p[i] == 0.0 and not friction:
                    continue
                idx = &kept[i, 0] if K > 0 else NULL
                n = 0
                while n < K and idx[n] >= 0:
                    n += 1
                m = 3 * (n + 1)
                built = n >= pa.k and element_one(
                    &pa, &nodes[0, 0], &contactors[i, 0], &origin[i, 0], &axes[i, 0, 0],
                    radius[i], &proximal[i, 0], idx, n, True, sc, &gap, Nb, Mb, W)
                if not built:
                    for j in range(m):
                        for v in range(m):
                            Mb[j * W + v] = NAN
                ok = add_block(&pl, &ids[i, 0], K + 1, &N[i, 0], Mb, eps[i], p[i],
                               &lam[i, 0] if multiplied else NULL,
                               &dT[i, 0, 0] if friction else NULL, bs)
                if not ok:
                    break
    finally:
        scratch_free(sc)
        block_scratch_free(bs)
        free(Mb)
    if not ok:
        raise ValueError("tangent_elements: an element's node pair is not in the pattern")

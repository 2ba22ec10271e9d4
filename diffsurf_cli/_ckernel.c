/* diffsurf's projection kernel: DiffuseSurface.select and DiffuseSurface._solve, one contactor
 * at a time, in parallel (OpenMP) over blocks of contactors. Loaded with ctypes by kernel.py,
 * which documents what it computes; this file is its arithmetic.
 *
 * It was ported from a numba kernel with the same arithmetic, operation for operation, so that
 * results are bit-for-bit those of the numba version. Python's semantics are kept where C's
 * differ: min(a, b) is `b < a ? b : a` and max(a, b) `b > a ? b : a` (not fmin/fmax: NaN
 * behaves differently), float `x % y` has the sign of y (py_mod), int(x) truncates. Built with
 * -ffp-contract=off (no fused multiply-add), as numba compiles.
 *
 * Arrays are C-contiguous; (n, 3) arrays are indexed [3 * row + column]. Indices are int64.
 */
#include <float.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#define PI 3.141592653589793 /* math.pi */

int diffsurf_threads(void) {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

/* Python's min and max on floats (the first argument unless the second compares less/more). */
static inline double py_min(double a, double b) { return b < a ? b : a; }
static inline double py_max(double a, double b) { return b > a ? b : a; }
static inline int64_t imin(int64_t a, int64_t b) { return b < a ? b : a; }
static inline int64_t imax(int64_t a, int64_t b) { return b > a ? b : a; }

/* Python's float x % y (Objects/floatobject.c): the remainder has the sign of y. */
static double py_mod(double x, double y) {
    double mod = fmod(x, y);
    if (mod != 0.0) { /* NaN included, as Python's `if (mod)` */
        if ((y < 0) != (mod < 0)) mod += y;
    } else {
        mod = y < 0.0 ? -0.0 : 0.0;
    }
    return mod;
}

static inline double sq(double x) { return x * x; } /* x ** 2 */

/* x**n for a small non-negative integer n, by multiplication (as basis.terms does). */
static inline double ipow(double x, int64_t n) {
    double out = 1.0;
    for (int64_t i = 0; i < n; i++) out *= x;
    return out;
}

/* ------------------------------------------------------------------------------------------ */
/* the grid of cells (kernel.build_grid): nodes of cell c are order[start[c]:start[c + 1]],    */
/* cell indices (i * dims[1] + j) * dims[2] + k                                                */
/* ------------------------------------------------------------------------------------------ */

typedef struct {
    const double *coords; /* (n, 3) */
    const double *lo;     /* (3,) lowest corner */
    double cell;          /* cell size */
    const int64_t *dims;  /* (3,) cells along each axis */
    const int64_t *start; /* (prod(dims) + 1,) */
    const int64_t *order; /* (n,) nodes sorted by cell */
} grid_t;

/* Cell of coordinate x along one axis, clamped to the grid (clamped as a float first: far
 * points stay finite ints). A NaN gives INT64_MIN, as numba's conversion does on x86-64: no
 * cell is then in range (see the wrapping sums in knn). */
static inline int64_t cell_index(double x, double lo, double cell, int64_t dim) {
    double c = (x - lo) / cell;
    c = py_min(py_max(c, 0.0), (double)dim - 1.0);
    if (isnan(c)) return INT64_MIN;
    return (int64_t)c;
}

/* a + b wrapping around as numba's int64 arithmetic does (no undefined overflow). */
static inline int64_t wrap_add(int64_t a, int64_t b) {
    return (int64_t)((uint64_t)a + (uint64_t)b);
}

/* Squared distance from node `node` of `coords` to the point p. */
static inline double distance2(const double *coords, int64_t node, const double *p) {
    double d2 = 0.0;
    for (int e = 0; e < 3; e++) {
        double d = coords[3 * node + e] - p[e];
        d2 += d * d;
    }
    return d2;
}

/* Insert (node, d2) into the list sorted by d2 whose first `pos` entries are filled (the entry
 * at `pos`, if any, is overwritten). */
static inline void insert_sorted(int64_t *idx, double *d2s, int64_t pos, int64_t node,
                                 double d2) {
    while (pos > 0 && d2s[pos - 1] > d2) {
        d2s[pos] = d2s[pos - 1];
        idx[pos] = idx[pos - 1];
        pos -= 1;
    }
    d2s[pos] = d2;
    idx[pos] = node;
}

/* The k nearest nodes of p, nearest first, in best_i/best_d2; returns how many (<= k). Layers
 * of cells around p's cell, until the k-th nearest is nearer than the next layer. */
static int64_t knn(const grid_t *g, const double *p, int64_t k, int64_t *best_i,
                   double *best_d2) {
    const int64_t *dims = g->dims;
    int64_t ci = cell_index(p[0], g->lo[0], g->cell, dims[0]);
    int64_t cj = cell_index(p[1], g->lo[1], g->cell, dims[1]);
    int64_t ck = cell_index(p[2], g->lo[2], g->cell, dims[2]);
    int64_t count = 0;
    int64_t layer = 0;
    int64_t last = imax(dims[0], imax(dims[1], dims[2]));
    for (;;) {
        for (int64_t di = -layer; di < layer + 1; di++) {
            int64_t i = wrap_add(ci, di);
            if (i < 0 || i >= dims[0]) continue;
            for (int64_t dj = -layer; dj < layer + 1; dj++) {
                int64_t j = wrap_add(cj, dj);
                if (j < 0 || j >= dims[1]) continue;
                int rim = llabs(di) == layer || llabs(dj) == layer;
                int64_t step = rim ? 1 : imax(2 * layer, 1);
                for (int64_t dk = -layer; dk < layer + 1; dk += step) {
                    int64_t kk = wrap_add(ck, dk);
                    if (kk < 0 || kk >= dims[2]) continue;
                    int64_t c = (i * dims[1] + j) * dims[2] + kk;
                    for (int64_t a = g->start[c]; a < g->start[c + 1]; a++) {
                        int64_t node = g->order[a];
                        double d2 = distance2(g->coords, node, p);
                        if (count == k && d2 >= best_d2[k - 1]) continue;
                        insert_sorted(best_i, best_d2, imin(count, k - 1), node, d2);
                        if (count < k) count += 1;
                    }
                }
            }
        }
        /* every cell of the next layer is at least `layer` cells away from p */
        if (count == k && best_d2[k - 1] <= sq((double)layer * g->cell)) break;
        if (layer >= last) break;
        layer += 1;
    }
    return count;
}

/* All nodes within r of p, nearest first when `sorted` (else in grid order: the support is a
 * set, and sorting it cost a third of the search); returns their number (only the first `cap`
 * are stored: a larger return value means the scratch was too small). */
static int64_t ball(const grid_t *g, const double *p, double r, int64_t cap, int64_t *out_i,
                    double *out_d2, int sorted) {
    const int64_t *dims = g->dims;
    int64_t i0 = cell_index(p[0] - r, g->lo[0], g->cell, dims[0]);
    int64_t i1 = cell_index(p[0] + r, g->lo[0], g->cell, dims[0]);
    int64_t j0 = cell_index(p[1] - r, g->lo[1], g->cell, dims[1]);
    int64_t j1 = cell_index(p[1] + r, g->lo[1], g->cell, dims[1]);
    int64_t k0 = cell_index(p[2] - r, g->lo[2], g->cell, dims[2]);
    int64_t k1 = cell_index(p[2] + r, g->lo[2], g->cell, dims[2]);
    double r2 = r * r;
    int64_t count = 0;
    if (i0 < 0 || j0 < 0 || k0 < 0) return 0; /* NaN: no cell (numba would read astray) */
    for (int64_t i = i0; i < i1 + 1; i++) {
        for (int64_t j = j0; j < j1 + 1; j++) {
            for (int64_t kk = k0; kk < k1 + 1; kk++) {
                int64_t c = (i * dims[1] + j) * dims[2] + kk;
                for (int64_t a = g->start[c]; a < g->start[c + 1]; a++) {
                    int64_t node = g->order[a];
                    double d2 = distance2(g->coords, node, p);
                    if (d2 <= r2) {
                        if (count < cap) {
                            if (sorted) {
                                insert_sorted(out_i, out_d2, count, node, d2);
                            } else {
                                out_i[count] = node;
                                out_d2[count] = d2;
                            }
                        }
                        count += 1;
                    }
                }
            }
        }
    }
    return count;
}

/* Move the `few` nearest of the first `count` entries to the front, nearest first (the first
 * of equal distances in their current order wins; the others keep no particular order). */
static void nearest_first(int64_t *idx, double *d2s, int64_t count, int64_t few) {
    for (int64_t a = 0; a < imin(few, count); a++) {
        int64_t best = a;
        for (int64_t j = a + 1; j < count; j++)
            if (d2s[j] < d2s[best]) best = j;
        int64_t ti = idx[a];
        double td = d2s[a];
        idx[a] = idx[best];
        d2s[a] = d2s[best];
        idx[best] = ti;
        d2s[best] = td;
    }
}

/* ------------------------------------------------------------------------------------------ */
/* small dense linear algebra                                                                   */
/* ------------------------------------------------------------------------------------------ */

/* kernel.constants(): indices of its entries */
enum {
    K_GAUSS_C2 = 0, K_GAUSS_TAIL = 1, K_SINGULAR_FLOOR = 2, K_NEWTON_STEP = 3,
    K_NEWTON_MAX_ITER = 4, K_E1_GUIDE = 5, K_E1_GUIDE_ALT = 8, K_EQUILIBRATION_FLOOR = 11
};

enum { WENDLAND = 0, GAUSS = 1, SINGULAR = 2 }; /* kernel.WEIGHT_CODES */

/* w(q), q = (rho/R)^2 [15]: as weight.py (0 outside the domain of influence). */
static double weight(int code, double q, const double *k) {
    if (q >= 1.0) return 0.0;
    if (code == GAUSS) return (exp(-q / k[K_GAUSS_C2]) - k[K_GAUSS_TAIL]) / (1.0 - k[K_GAUSS_TAIL]);
    double r = sqrt(q);
    double u = 1.0 - r;
    double w = u * u * u * u * (4.0 * r + 1.0);
    if (code == SINGULAR) return w / py_max(q, k[K_SINGULAR_FLOOR]);
    return w;
}

/* Unit eigenvector of the smallest eigenvalue of the symmetric 3x3 `c` (cyclic Jacobi). */
static void smallest_eigenvector(const double c[9], double out[3]) {
    static const int P[3] = {0, 0, 1}, Q[3] = {1, 2, 2};
    double a[9], v[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    memcpy(a, c, sizeof a);
    for (int sweep = 0; sweep < 50; sweep++) {
        double off = sq(a[1]) + sq(a[2]) + sq(a[5]);
        double scale = sq(a[0]) + sq(a[4]) + sq(a[8]);
        if (off <= 1e-36 * scale || off == 0.0) break;
        for (int pq = 0; pq < 3; pq++) {
            int p = P[pq], q = Q[pq];
            if (a[3 * p + q] == 0.0) continue;
            double theta = (a[3 * q + q] - a[3 * p + p]) / (2.0 * a[3 * p + q]);
            double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1.0));
            double cs = 1.0 / sqrt(t * t + 1.0);
            double sn = t * cs;
            for (int k = 0; k < 3; k++) { /* a <- J^T a J */
                double akp = a[3 * k + p], akq = a[3 * k + q];
                a[3 * k + p] = cs * akp - sn * akq;
                a[3 * k + q] = sn * akp + cs * akq;
            }
            for (int k = 0; k < 3; k++) {
                double apk = a[3 * p + k], aqk = a[3 * q + k];
                a[3 * p + k] = cs * apk - sn * aqk;
                a[3 * q + k] = sn * apk + cs * aqk;
            }
            for (int k = 0; k < 3; k++) {
                double vkp = v[3 * k + p], vkq = v[3 * k + q];
                v[3 * k + p] = cs * vkp - sn * vkq;
                v[3 * k + q] = sn * vkp + cs * vkq;
            }
        }
    }
    int j = 0;
    for (int i = 1; i < 3; i++)
        if (a[3 * i + i] < a[3 * j + j]) j = i;
    for (int k = 0; k < 3; k++) out[k] = v[3 * k + j];
}

/* Singular values of the n x n matrix r (destroyed), by one-sided Jacobi, into sig.
 *
 * Columns are rotated pairwise until all are orthogonal to 1e-9 (relative); the singular
 * values are then the column norms, accurate to far better than that (the error is second
 * order in the remaining off-orthogonality). */
static void singular_values(double *r, int64_t n, double *sig) {
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t k = 0; k < n; k++) acc += r[k * n + i] * r[k * n + i];
        sig[i] = acc; /* squared column norms, kept up to date through the rotations */
    }
    for (int sweep = 0; sweep < 60; sweep++) {
        int rotated = 0;
        for (int64_t i = 0; i < n - 1; i++) {
            for (int64_t j = i + 1; j < n; j++) {
                double alpha = sig[i];
                double beta = sig[j];
                double gamma = 0.0;
                for (int64_t k = 0; k < n; k++) gamma += r[k * n + i] * r[k * n + j];
                if (gamma == 0.0 || fabs(gamma) <= 1e-9 * sqrt(alpha * beta)) continue;
                rotated = 1;
                double zeta = (beta - alpha) / (2.0 * gamma);
                double t = (zeta >= 0 ? 1.0 : -1.0) / (fabs(zeta) + sqrt(1.0 + zeta * zeta));
                double cs = 1.0 / sqrt(1.0 + t * t);
                double sn = cs * t;
                for (int64_t k = 0; k < n; k++) {
                    double x = r[k * n + i], y = r[k * n + j];
                    r[k * n + i] = cs * x - sn * y;
                    r[k * n + j] = sn * x + cs * y;
                }
                sig[i] = alpha - t * gamma;
                sig[j] = beta + t * gamma;
            }
        }
        if (!rotated) break;
    }
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t k = 0; k < n; k++) acc += r[k * n + i] * r[k * n + i];
        sig[i] = sqrt(acc);
    }
}

/* Eigenvalues of the symmetric n x n matrix a (row stride n, destroyed) into d, in no order:
 * Householder reduction to tridiagonal form, then the implicit QL iteration (eigenvalues
 * only; as tred2/tqli in Numerical Recipes). `e` holds n. Returns 0, or 1 when QL did not
 * converge. */
static int symmetric_eigenvalues(double *a, int64_t n, double *d, double *e) {
    for (int64_t i = n - 1; i > 0; i--) {
        int64_t l = i - 1;
        double h = 0.0, scale = 0.0;
        if (l > 0) {
            for (int64_t k = 0; k <= l; k++) scale += fabs(a[i * n + k]);
            if (scale == 0.0) {
                e[i] = a[i * n + l];
            } else {
                for (int64_t k = 0; k <= l; k++) {
                    a[i * n + k] /= scale;
                    h += a[i * n + k] * a[i * n + k];
                }
                double f = a[i * n + l];
                double g = f >= 0.0 ? -sqrt(h) : sqrt(h);
                e[i] = scale * g;
                h -= f * g;
                a[i * n + l] = f - g;
                f = 0.0;
                for (int64_t j = 0; j <= l; j++) {
                    g = 0.0;
                    for (int64_t k = 0; k <= j; k++) g += a[j * n + k] * a[i * n + k];
                    for (int64_t k = j + 1; k <= l; k++) g += a[k * n + j] * a[i * n + k];
                    e[j] = g / h;
                    f += e[j] * a[i * n + j];
                }
                double hh = f / (h + h);
                for (int64_t j = 0; j <= l; j++) {
                    f = a[i * n + j];
                    e[j] = g = e[j] - hh * f;
                    for (int64_t k = 0; k <= j; k++) a[j * n + k] -= f * e[k] + g * a[i * n + k];
                }
            }
        } else {
            e[i] = a[i * n + l];
        }
    }
    for (int64_t i = 0; i < n; i++) d[i] = a[i * n + i];
    for (int64_t i = 1; i < n; i++) e[i - 1] = e[i];
    e[n - 1] = 0.0;
    for (int64_t l = 0; l < n; l++) {
        int iter = 0;
        int64_t m;
        do {
            for (m = l; m < n - 1; m++) {
                double dd = fabs(d[m]) + fabs(d[m + 1]);
                if (fabs(e[m]) <= DBL_EPSILON * dd) break;
            }
            if (m != l) {
                if (iter++ == 60) return 1;
                double g = (d[l + 1] - d[l]) / (2.0 * e[l]);
                double r = sqrt(g * g + 1.0);
                g = d[m] - d[l] + e[l] / (g + (g >= 0.0 ? r : -r));
                double sn = 1.0, cs = 1.0, p = 0.0;
                int64_t i;
                for (i = m - 1; i >= l; i--) {
                    double f = sn * e[i], b = cs * e[i];
                    e[i + 1] = (r = sqrt(f * f + g * g));
                    if (r == 0.0) { /* underflow: deflate */
                        d[i + 1] -= p;
                        e[m] = 0.0;
                        break;
                    }
                    sn = f / r;
                    cs = g / r;
                    g = d[i + 1] - p;
                    r = (d[i] - g) * sn + 2.0 * cs * b;
                    d[i + 1] = g + (p = sn * r);
                    g = cs * r - b;
                }
                if (r == 0.0 && i >= l) continue;
                d[l] -= p;
                e[l] = g;
                e[m] = 0.0;
            }
        } while (m != l);
    }
    return 0;
}

/* Below this, rcond is recomputed by one-sided Jacobi on R itself: from the eigenvalues of
 * R^T R its relative error is about n eps / rcond^2 (3e-11 at 1e-2, measured against LAPACK's
 * SVD), from Jacobi it stays near n eps whatever the conditioning. */
#define RCOND_GRAM_MIN 1e-2

/* sigma_min / sigma_max of the n x n upper triangular r (row stride n): from the extreme
 * eigenvalues of the Gram matrix r^T r (three times cheaper than Jacobi on r), or by Jacobi
 * when that is below RCOND_GRAM_MIN. `work` holds n * n, `sig` and `e` n each. */
static double triangular_rcond(const double *r, int64_t n, double *work, double *sig,
                               double *e) {
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j <= i; j++) {
            double acc = 0.0;
            for (int64_t k = 0; k <= j; k++) acc += r[k * n + i] * r[k * n + j];
            work[i * n + j] = work[j * n + i] = acc;
        }
    if (!symmetric_eigenvalues(work, n, sig, e)) {
        double top = sig[0], low = sig[0];
        for (int64_t i = 1; i < n; i++) {
            top = py_max(top, sig[i]);
            low = py_min(low, sig[i]);
        }
        double rc = top > 0.0 && low > 0.0 ? sqrt(low / top) : 0.0;
        if (rc >= RCOND_GRAM_MIN) return rc;
    }
    memcpy(work, r, (size_t)(n * n) * sizeof *work);
    singular_values(work, n, sig);
    double top = 0.0;
    double low = INFINITY;
    for (int64_t i = 0; i < n; i++) {
        top = py_max(top, sig[i]);
        low = py_min(low, sig[i]);
    }
    return top > 0 ? low / top : 0.0;
}

/* Householder QR of the m x n matrix `a` (row stride n, in place), applied to b[:m] unless b
 * is NULL; copies R into rfac (n x n) and returns sigma_min/sigma_max of R, which are those of
 * `a` (0 when m < n or all zero). `work` holds n * n. */
static double qr_rcond(double *a, int64_t m, int64_t n, double *b, double *rfac, double *sig,
                       double *work) {
    if (m < n) return 0.0;
    for (int64_t j = 0; j < n; j++) {
        double norm = 0.0;
        for (int64_t i = j; i < m; i++) norm += a[i * n + j] * a[i * n + j];
        norm = sqrt(norm);
        if (norm == 0.0) continue;
        double ajj = a[j * n + j];
        double alpha = ajj >= 0 ? -norm : norm;
        double v0 = ajj - alpha;
        /* v = (v0, a[j+1:, j]); H = I - 2 v v^T / v^T v */
        double vtv = v0 * v0 + (norm * norm - ajj * ajj);
        if (vtv <= 0.0) continue;
        a[j * n + j] = v0;
        for (int64_t c = j + 1; c < n; c++) {
            double dot = 0.0;
            for (int64_t i = j; i < m; i++) dot += a[i * n + j] * a[i * n + c];
            double f = 2.0 * dot / vtv;
            for (int64_t i = j; i < m; i++) a[i * n + c] -= f * a[i * n + j];
        }
        if (b) {
            double dot = 0.0;
            for (int64_t i = j; i < m; i++) dot += a[i * n + j] * b[i];
            double f = 2.0 * dot / vtv;
            for (int64_t i = j; i < m; i++) b[i] -= f * a[i * n + j];
        }
        a[j * n + j] = alpha;
        for (int64_t i = j + 1; i < m; i++) a[i * n + j] = 0.0;
    }
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) rfac[i * n + j] = j >= i ? a[i * n + j] : 0.0;
    return triangular_rcond(rfac, n, work, sig, sig + n);
}

/* The monomials s^ea[j] t^eb[j] of the basis [16]. */
typedef struct {
    const int64_t *ea, *eb;
    int64_t n; /* number of terms */
} basis_t;

/* Per-block scratch of the least squares. */
typedef struct {
    double *a;     /* (max(cap, n), n) */
    double *b;     /* (max(cap, n),) */
    double *rfac;  /* (n, n) */
    double *work;  /* (n, n) */
    double *sig;   /* (2n,): singular values or eigenvalues, then scratch */
    double *scale; /* (n,) */
} lsq_t;

/* The rows sqrt(w/w_max) p(s, t) of the support nodes with w > 0 into `a` (and sqrt(w/w_max) z
 * into `b`, unless NULL), columns equilibrated, their norms in `scale`, as fit.py; returns the
 * number of rows. */
static int64_t weighted_system(const basis_t *bs, const double *s, const double *t,
                               const double *z, const double *w, int64_t count, double *a,
                               double *b, double *scale, double floor_) {
    int64_t n = bs->n;
    double wmax = 0.0;
    for (int64_t r = 0; r < count; r++) wmax = py_max(wmax, w[r]);
    int64_t rows = 0;
    for (int64_t r = 0; r < count; r++) {
        if (w[r] <= 0.0) continue;
        double root = sqrt(w[r] / wmax);
        for (int64_t j = 0; j < n; j++)
            a[rows * n + j] = root * ipow(s[r], bs->ea[j]) * ipow(t[r], bs->eb[j]);
        if (b) b[rows] = root * z[r];
        rows += 1;
    }
    double top = 0.0;
    for (int64_t j = 0; j < n; j++) {
        double c = 0.0;
        for (int64_t i = 0; i < rows; i++) c += a[i * n + j] * a[i * n + j];
        scale[j] = sqrt(c);
        top = py_max(top, scale[j]);
    }
    for (int64_t j = 0; j < n; j++) {
        /* floored: a column of round-off (a support on a line) must stay negligible */
        scale[j] = py_max(scale[j], floor_ * top);
        if (!(scale[j] > 0)) scale[j] = 1.0;
        for (int64_t i = 0; i < rows; i++) a[i * n + j] /= scale[j];
    }
    return rows;
}

/* Weighted least squares [17] of the support rows with w > 0 (the first `count` entries of s,
 * t, z, w, geo): alpha (NaN when impossible) and the rcond fit.py computes (on the smooth
 * weights `geo` when use_geo). */
static double fit(const basis_t *bs, const double *s, const double *t, const double *z,
                  const double *w, const double *geo, int64_t count, lsq_t *ls, double *alpha,
                  int use_geo, double floor_) {
    int64_t n = bs->n;
    int64_t rows = weighted_system(bs, s, t, z, w, count, ls->a, ls->b, ls->scale, floor_);
    double rcond = qr_rcond(ls->a, rows, n, ls->b, ls->rfac, ls->sig, ls->work);
    if (rcond > 0.0) {
        for (int64_t j = n - 1; j >= 0; j--) { /* back substitution R y = Q^T b */
            double acc = ls->b[j];
            for (int64_t c = j + 1; c < n; c++) acc -= ls->rfac[j * n + c] * alpha[c];
            alpha[j] = acc / ls->rfac[j * n + j];
        }
        for (int64_t j = 0; j < n; j++) alpha[j] /= ls->scale[j];
        for (int64_t j = 0; j < n; j++) {
            if (!isfinite(alpha[j])) {
                for (int64_t i = 0; i < n; i++) alpha[i] = NAN;
                break;
            }
        }
    } else {
        for (int64_t i = 0; i < n; i++) alpha[i] = NAN;
    }
    if (use_geo) {
        /* the singular weight is stiff by design: judge the support's geometry on the smooth
           weight with the same support (as fit.py's `geometry`) */
        rows = weighted_system(bs, s, t, z, geo, count, ls->a, NULL, ls->scale, floor_);
        rcond = qr_rcond(ls->a, rows, n, NULL, ls->rfac, ls->sig, ls->work);
    }
    return rcond;
}

/* f, f,s, f,t, f,ss, f,st, f,tt of the local approximation at (s, t) into out[6]. */
static void surface_derivatives(const basis_t *bs, const double *alpha, double s, double t,
                                double *out) {
    for (int d = 0; d < 6; d++) out[d] = 0.0;
    for (int64_t j = 0; j < bs->n; j++) {
        int64_t a = bs->ea[j];
        int64_t b = bs->eb[j];
        double sa = ipow(s, a);
        double tb = ipow(t, b);
        double sa1 = a >= 1 ? (double)a * ipow(s, a - 1) : 0.0;
        double tb1 = b >= 1 ? (double)b * ipow(t, b - 1) : 0.0;
        double sa2 = a >= 2 ? (double)(a * (a - 1)) * ipow(s, a - 2) : 0.0;
        double tb2 = b >= 2 ? (double)(b * (b - 1)) * ipow(t, b - 2) : 0.0;
        out[0] += alpha[j] * sa * tb;
        out[1] += alpha[j] * sa1 * tb;
        out[2] += alpha[j] * sa * tb1;
        out[3] += alpha[j] * sa2 * tb;
        out[4] += alpha[j] * sa1 * tb1;
        out[5] += alpha[j] * sa * tb2;
    }
}

/* proximal_point() of surface.py for one point c (local, divided by R) [30]-[31]: the foot
 * (st[0], st[1]) by Newton's method on the squared distance, f at the last iterate in f;
 * returns the iterations, *converged whether it converged. */
static int64_t newton(const basis_t *bs, const double *alpha, const double c[3], double f[6],
                      double st[2], const double *k, int *converged) {
    st[0] = c[0];
    st[1] = c[1];
    *converged = 0;
    for (int64_t j = 0; j < bs->n; j++)
        if (!isfinite(alpha[j])) return 0;
    int64_t its = 0;
    int64_t max_iter = (int64_t)k[K_NEWTON_MAX_ITER];
    for (int64_t it = 0; it < max_iter; it++) {
        surface_derivatives(bs, alpha, st[0], st[1], f);
        double r = f[0] - c[2];
        double fs = f[1], ft = f[2], fss = f[3], fst = f[4], ftt = f[5];
        double g1 = st[0] - c[0] + r * fs;
        double g2 = st[1] - c[1] + r * ft;
        double h11 = 1 + fs * fs + r * fss;
        double h12 = fs * ft + r * fst;
        double h22 = 1 + ft * ft + r * ftt;
        double det = h11 * h22 - h12 * h12;
        int gn = !(det > 0 && h11 > 0);
        if (gn) { /* Gauss-Newton beyond a focal point */
            h11 = 1 + fs * fs;
            h12 = fs * ft;
            h22 = 1 + ft * ft;
            det = h11 * h22 - h12 * h12;
        }
        double d1 = -(h22 * g1 - h12 * g2) / det;
        double d2 = -(h11 * g2 - h12 * g1) / det;
        double step = hypot(d1, d2);
        double cap = step > 0.5 ? 0.5 / step : 1.0;
        st[0] += cap * d1;
        st[1] += cap * d2;
        its += 1;
        if (step < k[K_NEWTON_STEP] && !gn) {
            *converged = 1;
            return its;
        }
        if (!isfinite(step)) return its;
    }
    return its;
}

/* surface._beyond_hull for one point at (s0, t0): whether it is farther than `slack` from the
 * in-plane convex hull of the support nodes with w > 0 (free arc of directions >= pi). `start`
 * and `end` are scratch of `count` entries. */
static int beyond_hull(const double *s, const double *t, const double *w, int64_t count,
                       double s0, double t0, double slack, double *start, double *end) {
    /* quick accept: a live node in each open quadrant around the point puts the point inside
       their convex hull (no line through it has them all on one side) */
    int quadrants = 0;
    for (int64_t j = 0; j < count; j++) {
        if (w[j] > 0) {
            double ds = s[j] - s0;
            double dt = t[j] - t0;
            if (ds > 0 && dt > 0) quadrants |= 1;
            else if (ds < 0 && dt > 0) quadrants |= 2;
            else if (ds < 0 && dt < 0) quadrants |= 4;
            else if (ds > 0 && dt < 0) quadrants |= 8;
        }
    }
    if (quadrants == 15) return 0;
    double two_pi = 2.0 * PI;
    int64_t live = 0;
    for (int64_t j = 0; j < count; j++) {
        if (w[j] <= 0) continue;
        double ds = s[j] - s0;
        double dt = t[j] - t0;
        double r = hypot(ds, dt);
        if (r <= slack) return 0; /* within the slack of a node */
        double half = asin(py_min(slack / r, 1.0));
        double a = py_mod(atan2(dt, ds) - half, two_pi);
        /* insertion by start angle */
        int64_t pos = live;
        while (pos > 0 && start[pos - 1] > a) {
            start[pos] = start[pos - 1];
            end[pos] = end[pos - 1];
            pos -= 1;
        }
        start[pos] = a;
        end[pos] = a + 2.0 * half;
        live += 1;
    }
    if (live == 0) return 0;
    for (int64_t j = 1; j < live; j++) end[j] = py_max(end[j], end[j - 1]); /* farthest end */
    double wrapped = end[live - 1] - two_pi;
    double free_arc = start[0] - wrapped;
    for (int64_t j = 1; j < live; j++)
        free_arc = py_max(free_arc, start[j] - py_max(end[j - 1], wrapped));
    return free_arc >= PI;
}

/* ------------------------------------------------------------------------------------------ */
/* the local frame                                                                              */
/* ------------------------------------------------------------------------------------------ */

/* frame.in_plane_axis for one e3 (guides k[5:8] and k[8:11]). */
static void frame_e1(const double e3[3], double out[3], const double *k) {
    const double *g = k + K_E1_GUIDE;
    double dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2];
    double norm = sqrt(sq(g[0]) + sq(g[1]) + sq(g[2]));
    if (!(fabs(dot) < 0.9 * norm)) g = k + K_E1_GUIDE_ALT;
    dot = g[0] * e3[0] + g[1] * e3[1] + g[2] * e3[2];
    for (int e = 0; e < 3; e++) out[e] = g[e] - dot * e3[e];
}

/* frame._right_handed: rows e1 (orthogonalised, unit), e2 = e3 x e1, e3 of axes (3x3). */
static void right_handed(double e1[3], const double e3[3], double axes[9]) {
    double dot = e1[0] * e3[0] + e1[1] * e3[1] + e1[2] * e3[2];
    for (int e = 0; e < 3; e++) e1[e] -= dot * e3[e];
    double norm = sqrt(sq(e1[0]) + sq(e1[1]) + sq(e1[2]));
    for (int e = 0; e < 3; e++) {
        axes[e] = e1[e] / norm;
        axes[6 + e] = e3[e];
    }
    axes[3] = e3[1] * axes[2] - e3[2] * axes[1];
    axes[4] = e3[2] * axes[0] - e3[0] * axes[2];
    axes[5] = e3[0] * axes[1] - e3[1] * axes[0];
}

/* ------------------------------------------------------------------------------------------ */
/* one contactor                                                                                */
/* ------------------------------------------------------------------------------------------ */

/* The target as surface.py holds it (n nodes). */
typedef struct {
    const double *nodes;        /* (n, 3) */
    const double *normals;      /* (n, 3) nodal normals (faces only) */
    const double *node_spacing; /* (n,) */
    const int64_t *first;       /* (n,) first node at the same position */
    const double *fold_normals; /* (n, 3) */
    const uint8_t *is_signed;   /* (n,) whether fold_normals is oriented */
    const uint8_t *steep;       /* (n,) */
    grid_t grid;                /* grid of the nodes */
    grid_t plane;               /* grid of the nodes in the global frame's plane */
    const double *frame_origin; /* (3,) global frame */
    const double *frame_axes;   /* (3, 3) */
    int64_t has_faces, duplicates, global_frame;
} target_t;

/* The options of the projection (surface.py's constants and the surface's settings). */
typedef struct {
    basis_t basis;
    int64_t weight_code;        /* WEIGHT_CODES */
    int64_t knn;                /* support: k nearest (else radius) */
    int64_t k;                  /* k nearest */
    int64_t spacing_neighbours; /* nodes averaged for the spacing h */
    double radius;              /* support radius in spacings */
    double frame_ball;          /* frame ball / support radius */
    double knn_factor;          /* R / farthest in-plane distance (knn) */
    double sheet_cos;           /* nodes facing farther than this are another sheet */
    double cos_fold;            /* steep beyond this */
    double rcond_min, contact_tol, outside_spacings, hull_spacings;
    const double *consts;       /* kernel.constants() */
} options_t;

/* The outputs, (m, ...) each: the Projection fields and the pairing. */
typedef struct {
    double *gap, *normal, *proximal; /* (m,), (m, 3), (m, 3) */
    int8_t *status, *reason;
    int64_t *support, *iterations;
    double *rcond, *curvature;       /* (m,), (m, 2) */
    double *origin, *axes, *radius, *spacing; /* (m, 3), (m, 3, 3), (m,), (m,) */
    int64_t *index;                  /* (m, width) support nodes, padded with -1 */
    int64_t width;
    uint8_t *overflow;               /* (m,) the support had more than cap nodes */
} outputs_t;

/* Per-block scratch (cap support nodes). */
typedef struct {
    int64_t *cand_i, *near_i;
    double *cand_d2, *near_d2, *s, *t, *z, *w, *geo, *arc_start, *arc_end, *alpha;
    lsq_t ls;
    void *mem;
} scratch_t;

static int scratch_alloc(scratch_t *sc, int64_t cap, int64_t nterms, int64_t near) {
    int64_t rows = imax(cap, nterms);
    size_t doubles = (size_t)(9 * cap + near + rows * nterms + rows + 2 * nterms * nterms
                              + 4 * nterms);
    size_t ints = (size_t)(cap + near);
    char *mem = malloc(doubles * sizeof(double) + ints * sizeof(int64_t));
    if (!mem) return -1;
    double *d = (double *)mem;
    sc->cand_d2 = d; d += cap;
    sc->s = d; d += cap;
    sc->t = d; d += cap;
    sc->z = d; d += cap;
    sc->w = d; d += cap;
    sc->geo = d; d += cap;
    sc->arc_start = d; d += cap;
    sc->arc_end = d; d += cap;
    d += cap; /* spare */
    sc->near_d2 = d; d += near;
    sc->ls.a = d; d += rows * nterms;
    sc->ls.b = d; d += rows;
    sc->ls.rfac = d; d += nterms * nterms;
    sc->ls.work = d; d += nterms * nterms;
    sc->ls.sig = d; d += 2 * nterms; /* sig, then the eigen-solver's e */
    sc->ls.scale = d; d += nterms;
    sc->alpha = d; d += nterms;
    int64_t *i = (int64_t *)d;
    sc->cand_i = i; i += cap;
    sc->near_i = i;
    sc->mem = mem;
    return 0;
}

/* Support and frame of one contactor (surface.py `select`) around `ref`, h its spacing:
 * the support nodes in cand_i[:count] (cand_d2 their squared distances to the search point),
 * axes, R. */
static int64_t select_support(const target_t *tg, const options_t *op, const double *ref,
                              double h, int64_t cap, scratch_t *sc, double axes[9], double *R_out,
                              uint8_t *overflow) {
    const double *nodes = tg->nodes, *normals = tg->normals, *frame_axes = tg->frame_axes;
    const double *consts = op->consts;
    int64_t *cand_i = sc->cand_i;
    double *cand_d2 = sc->cand_d2, *geo = sc->geo;
    double pp[3], foot[3], e1[3], e3[3], cov[9];
    double R = 0.0;
    int64_t count = 0;
    if (tg->global_frame) {
        for (int e = 0; e < 9; e++) axes[e] = frame_axes[e];
        for (int e = 0; e < 2; e++) {
            pp[e] = 0.0;
            for (int col = 0; col < 3; col++)
                pp[e] += frame_axes[3 * e + col] * (ref[col] - tg->frame_origin[col]);
        }
        pp[2] = 0.0;
        if (op->knn) {
            count = knn(&tg->plane, pp, op->k, cand_i, cand_d2);
            R = op->knn_factor * sqrt(cand_d2[count > 0 ? count - 1 : cap - 1]);
        } else {
            R = op->radius * h;
            count = ball(&tg->plane, pp, R, cap, cand_i, cand_d2, 0);
            if (count > cap) {
                *overflow = 1;
                count = cap;
            }
        }
        *R_out = R;
        return count;
    }
    /* the reference's foot on the tangent plane of its nearest node */
    int64_t n0 = sc->near_i[0];
    double dn = 0.0;
    for (int e = 0; e < 3; e++) {
        foot[e] = ref[e];
        if (tg->has_faces) dn += (ref[e] - nodes[3 * n0 + e]) * normals[3 * n0 + e];
    }
    for (int e = 0; e < 3; e++)
        foot[e] = tg->has_faces ? ref[e] - dn * normals[3 * n0 + e] : nodes[3 * n0 + e];
    double ballr;
    if (op->knn) {
        count = knn(&tg->grid, foot, op->k, cand_i, cand_d2);
        ballr = 1.0001 * sqrt(cand_d2[count > 0 ? count - 1 : cap - 1]);
    } else {
        R = op->radius * h;
        ballr = op->frame_ball * R;
        count = ball(&tg->grid, foot, ballr, cap, cand_i, cand_d2, 0);
        if (count > cap) {
            *overflow = 1;
            count = cap;
        }
        nearest_first(cand_i, cand_d2, count, 3); /* the sheet test below reads these */
    }
    if (tg->has_faces) {
        /* drop the nodes of another sheet (far side of a thin tube or plate) */
        for (int e = 0; e < 3; e++) e3[e] = 0.0;
        for (int64_t j = 0; j < imin(count, 3); j++)
            for (int e = 0; e < 3; e++) e3[e] += normals[3 * cand_i[j] + e];
        double nn = py_max(sqrt(sq(e3[0]) + sq(e3[1]) + sq(e3[2])), 1e-300);
        int64_t kept = 0;
        for (int64_t j = 0; j < count; j++) {
            int64_t node = cand_i[j];
            const double *nv = normals + 3 * node;
            double facing = (nv[0] * e3[0] + nv[1] * e3[1] + nv[2] * e3[2]) / nn;
            if (facing >= op->sheet_cos) {
                cand_i[kept] = node;
                cand_d2[kept] = cand_d2[j];
                kept += 1;
            }
        }
        count = kept;
    }
    /* weighted PCA over the ball (frame.local_axes) */
    double wsum = 0.0;
    for (int e = 0; e < 3; e++) pp[e] = 0.0;
    for (int64_t j = 0; j < count; j++) {
        double wj = weight(WENDLAND, cand_d2[j] / (ballr * ballr), consts);
        geo[j] = wj;
        wsum += wj;
        for (int e = 0; e < 3; e++) pp[e] += wj * (nodes[3 * cand_i[j] + e] - foot[e]);
    }
    if (wsum > 0)
        for (int e = 0; e < 3; e++) pp[e] /= wsum;
    for (int e = 0; e < 9; e++) cov[e] = 0.0;
    for (int64_t j = 0; j < count; j++) {
        const double *x = nodes + 3 * cand_i[j];
        for (int r = 0; r < 3; r++) {
            double dr = x[r] - foot[r] - pp[r];
            for (int col = r; col < 3; col++) {
                double dc = x[col] - foot[col] - pp[col];
                cov[3 * r + col] += geo[j] * dr * dc;
            }
        }
    }
    cov[3] = cov[1];
    cov[6] = cov[2];
    cov[7] = cov[5];
    smallest_eigenvector(cov, e3);
    double dot = 0.0;
    for (int64_t j = 0; j < count; j++) {
        for (int e = 0; e < 3; e++) {
            double guide = tg->has_faces ? normals[3 * cand_i[j] + e] : frame_axes[6 + e];
            dot += geo[j] * guide * e3[e];
        }
    }
    if (dot < 0)
        for (int e = 0; e < 3; e++) e3[e] = -e3[e];
    frame_e1(e3, e1, consts);
    right_handed(e1, e3, axes);
    if (op->knn) {
        R = 0.0;
        for (int64_t j = 0; j < count; j++) {
            double u0 = 0.0, u1 = 0.0;
            for (int col = 0; col < 3; col++) {
                double d = nodes[3 * cand_i[j] + col] - ref[col];
                u0 += axes[col] * d;
                u1 += axes[3 + col] * d;
            }
            R = py_max(R, sqrt(u0 * u0 + u1 * u1));
        }
        R = R > 0 ? op->knn_factor * R : op->radius * h;
    }
    *R_out = R;
    return count;
}

/* Project contactor i (surface.py `select`, then `_solve`). */
static void project_one(const target_t *tg, const options_t *op, const double *x,
                        const double *ref, int centred, int64_t cap, scratch_t *sc,
                        const outputs_t *out, int64_t i) {
    const double *nodes = tg->nodes, *consts = op->consts;
    const basis_t *bs = &op->basis;
    int64_t nterms = bs->n;
    int64_t *cand_i = sc->cand_i;
    double *cand_d2 = sc->cand_d2, *s = sc->s, *t = sc->t, *z = sc->z, *w = sc->w;
    double *geo = sc->geo;
    double axes[9], c[3], f[6], st[2], R;
    /* -- local node spacing h: mean over the nearest nodes of their spacing */
    int64_t got = knn(&tg->grid, ref, op->spacing_neighbours, sc->near_i, sc->near_d2);
    double h = 0.0;
    for (int64_t j = 0; j < got; j++) h += tg->node_spacing[sc->near_i[j]];
    h /= (double)got;
    /* -- support and frame (surface.py `select`) */
    int64_t count = select_support(tg, op, ref, h, cap, sc, axes, &R, &out->overflow[i]);
    /* -- fit and projection (surface.py `_solve`) */
    if (tg->duplicates) { /* each position once, as its first occurrence */
        int64_t kept = 0;
        for (int64_t j = 0; j < count; j++) {
            int64_t node = tg->first[cand_i[j]];
            int seen = 0;
            for (int64_t jj = 0; jj < kept; jj++) {
                if (cand_i[jj] == node) {
                    seen = 1;
                    break;
                }
            }
            if (!seen) {
                cand_i[kept] = node;
                cand_d2[kept] = cand_d2[j];
                kept += 1;
            }
        }
        count = kept;
    }
    for (int e = 0; e < 3; e++) {
        c[e] = 0.0;
        for (int col = 0; col < 3; col++) c[e] += axes[3 * e + col] * (x[col] - ref[col]);
        c[e] /= R;
    }
    double c0 = centred ? c[0] : 0.0;
    double c1 = centred ? c[1] : 0.0;
    int64_t positive = 0;
    for (int64_t j = 0; j < count; j++) {
        double X0 = 0.0, X1 = 0.0, X2 = 0.0;
        for (int col = 0; col < 3; col++) {
            double d = nodes[3 * cand_i[j] + col] - ref[col];
            X0 += axes[col] * d;
            X1 += axes[3 + col] * d;
            X2 += axes[6 + col] * d;
        }
        s[j] = X0 / R - c0;
        t[j] = X1 / R - c1;
        z[j] = X2 / R;
        double q = s[j] * s[j] + t[j] * t[j];
        w[j] = weight((int)op->weight_code, q, consts);
        if (op->weight_code == SINGULAR) geo[j] = weight(WENDLAND, q, consts); /* fit's use_geo */
        if (w[j] > 0) positive += 1;
    }
    double rc = fit(bs, s, t, z, w, geo, count, &sc->ls, sc->alpha, op->weight_code == SINGULAR,
                    consts[K_EQUILIBRATION_FLOOR]);
    c[0] -= c0;
    c[1] -= c1;
    int ok;
    int64_t its = newton(bs, sc->alpha, c, f, st, consts, &ok);
    surface_derivatives(bs, sc->alpha, st[0], st[1], f);
    /* [29]: nu = (-f,1, -f,2, 1)/|.| in the frame */
    double nrm = sqrt(f[1] * f[1] + f[2] * f[2] + 1.0);
    double nu0 = -f[1] / nrm, nu1 = -f[2] / nrm, nu2 = 1.0 / nrm;
    double *normal = out->normal + 3 * i, *proximal = out->proximal + 3 * i;
    double g = 0.0;
    for (int col = 0; col < 3; col++) {
        normal[col] = axes[col] * nu0 + axes[3 + col] * nu1 + axes[6 + col] * nu2;
        proximal[col] = ref[col] + R * (axes[col] * (st[0] + c0) + axes[3 + col] * (st[1] + c1)
                                        + axes[6 + col] * f[0]);
        g += (x[col] - proximal[col]) * normal[col];
    }
    out->gap[i] = g; /* [32] */
    int code = g > 0 ? 0 : 2; /* open / penetration [33] */
    if (fabs(g) <= op->contact_tol * h) code = 1;
    int why = 0;
    /* the proximal point must lie on the target: near a support node, inside the domain of
       influence, within the in-plane hull of the support */
    double d2min = INFINITY;
    int beyond = beyond_hull(s, t, w, count, st[0], st[1], op->hull_spacings * h / R,
                             sc->arc_start, sc->arc_end);
    for (int64_t j = 0; j < count; j++)
        if (w[j] > 0) d2min = py_min(d2min, sq(s[j] - st[0]) + sq(t[j] - st[1]));
    if (sqrt(d2min) * R > op->outside_spacings * h || st[0] * st[0] + st[1] * st[1] > 1.0
        || beyond) {
        code = 3;
        why = 4; /* off-target */
    }
    if (!ok) {
        code = 4;
        why = 5; /* no-convergence */
    }
    if (!(rc >= op->rcond_min)) {
        code = 3;
        why = 3; /* ill-conditioned */
    }
    if (positive < nterms) {
        code = 3;
        why = 2; /* few-nodes */
    }
    /* a support reaching where the target turns vertical or folds over the frame */
    for (int64_t j = 0; j < count; j++) {
        if (w[j] <= 0) continue;
        int64_t node = cand_i[j];
        const double *fn = tg->fold_normals + 3 * node;
        double facing = fn[0] * axes[6] + fn[1] * axes[7] + fn[2] * axes[8];
        if (!tg->is_signed[node]) facing = fabs(facing);
        if (facing < op->cos_fold || tg->steep[node]) {
            code = 3;
            why = 7; /* steep */
            break;
        }
    }
    out->status[i] = (int8_t)code;
    out->reason[i] = (int8_t)why;
    out->support[i] = positive;
    out->iterations[i] = its;
    out->rcond[i] = rc;
    /* principal curvatures (surface.principal_curvatures), divided by R */
    double fs = f[1], ft = f[2];
    double E = 1 + fs * fs, F = fs * ft, G = 1 + ft * ft;
    double root = sqrt(1 + fs * fs + ft * ft);
    double L = -f[3] / root, M = -f[4] / root, N = -f[5] / root;
    double det = E * G - F * F;
    double mean = (E * N + G * L - 2 * F * M) / (2 * det);
    double gauss = (L * N - M * M) / det;
    double disc = sqrt(py_max(mean * mean - gauss, 0.0));
    double *curvature = out->curvature + 2 * i;
    curvature[0] = (mean + disc) / R;
    curvature[1] = (mean - disc) / R;
    if (code >= 3) {
        out->gap[i] = NAN;
        for (int col = 0; col < 3; col++) {
            normal[col] = NAN;
            proximal[col] = NAN;
        }
        curvature[0] = NAN;
        curvature[1] = NAN;
    }
    /* the pairing */
    for (int e = 0; e < 3; e++) out->origin[3 * i + e] = ref[e];
    for (int e = 0; e < 9; e++) out->axes[9 * i + e] = axes[e];
    out->radius[i] = R;
    out->spacing[i] = h;
    int64_t kept = imin(count, out->width);
    int64_t *index = out->index + out->width * i;
    for (int64_t j = 0; j < kept; j++) index[j] = cand_i[j];
    for (int64_t j = kept; j < out->width; j++) index[j] = -1;
}

/* ------------------------------------------------------------------------------------------ */
/* entry points (ctypes)                                                                        */
/* ------------------------------------------------------------------------------------------ */

/* Project the m `points` with supports selected around `reference` (see kernel.project), in
 * parallel over blocks of rows on `threads` threads (0: OpenMP's default). overflow[i] is set
 * where the support had more than `cap` nodes (the caller retries those rows with a larger
 * cap). Returns 0, or -1 when scratch memory could not be allocated. */
int diffsurf_project(const target_t *tg, const options_t *op, int64_t m, const double *points,
                     const double *reference, int64_t centred, int64_t cap, int64_t threads,
                     const outputs_t *out) {
    if (threads <= 0) threads = diffsurf_threads();
    int64_t nblocks = imax(1, imin(m, 64 * threads));
    int failed = 0;
    for (int64_t i = 0; i < m; i++) out->overflow[i] = 0;
#pragma omp parallel for schedule(dynamic) num_threads((int)threads)
    for (int64_t blk = 0; blk < nblocks; blk++) {
        int64_t lo_row = blk * m / nblocks;
        int64_t hi_row = (blk + 1) * m / nblocks;
        scratch_t sc; /* once per block */
        if (scratch_alloc(&sc, cap, op->basis.n, op->spacing_neighbours) != 0) {
#pragma omp atomic write
            failed = 1;
            continue;
        }
        for (int64_t i = lo_row; i < hi_row; i++)
            project_one(tg, op, points + 3 * i, reference + 3 * i, (int)centred, cap, &sc, out,
                        i);
        free(sc.mem);
    }
    return failed ? -1 : 0;
}

/* Distances (n, k) from each node of the grid to its k nearest (itself first), nearest first,
 * inf past the n-th. Returns 0, or -1 when scratch memory could not be allocated. */
int diffsurf_nearest_distances(const double *coords, int64_t n, const double *lo, double cell,
                               const int64_t *dims, const int64_t *start, const int64_t *order,
                               int64_t k, double *out) {
    grid_t g = {coords, lo, cell, dims, start, order};
    int failed = 0;
#pragma omp parallel
    {
        int64_t *idx = malloc((size_t)imax(k, 1) * sizeof *idx);
        double *d2 = malloc((size_t)imax(k, 1) * sizeof *d2);
        if (!idx || !d2) {
#pragma omp atomic write
            failed = 1;
        }
#pragma omp for schedule(static)
        for (int64_t i = 0; i < n; i++) {
            if (!idx || !d2) continue;
            int64_t got = knn(&g, coords + 3 * i, k, idx, d2);
            for (int64_t j = 0; j < k; j++) out[k * i + j] = j < got ? sqrt(d2[j]) : INFINITY;
        }
        free(idx);
        free(d2);
    }
    return failed ? -1 : 0;
}

/* One k-nearest search (kernel._knn): returns how many were found (<= k). */
int64_t diffsurf_knn(const double *coords, const double *lo, double cell, const int64_t *dims,
                     const int64_t *start, const int64_t *order, const double *p, int64_t k,
                     int64_t *best_i, double *best_d2) {
    grid_t g = {coords, lo, cell, dims, start, order};
    return knn(&g, p, k, best_i, best_d2);
}

/* One ball search (kernel._ball): returns the number of nodes within r (the first cap are
 * stored). */
int64_t diffsurf_ball(const double *coords, const double *lo, double cell, const int64_t *dims,
                      const int64_t *start, const int64_t *order, const double *p, double r,
                      int64_t cap, int64_t *out_i, double *out_d2) {
    grid_t g = {coords, lo, cell, dims, start, order};
    return ball(&g, p, r, cap, out_i, out_d2, 1);
}

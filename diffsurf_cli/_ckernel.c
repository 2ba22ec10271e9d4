/* diffsurf's projection kernel (see kernel.py). Placeholder: being ported from numba. */
#ifdef _OPENMP
#include <omp.h>
#endif

int diffsurf_threads(void) {
#ifdef _OPENMP
    return omp_get_max_threads();
#else
    return 1;
#endif
}

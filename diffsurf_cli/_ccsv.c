/* diffsurf's CSV tokeniser, float parser and shortest float formatter (see fastcsv.py).
   Placeholder: being ported from numba. */
int diffsurf_ccsv_version(void) { return 1; }

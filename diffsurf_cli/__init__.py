"""diffsurf: diffuse (moving least squares) smoothing of faceted contact surfaces.

The numerical core (frames, bases, weights, support, fit, projection, contact element) works
on numpy arrays only; ``diffsurf_cli.io`` is the one module that touches files and
``diffsurf_cli.cli`` is the thin command-line layer.
"""
__version__ = "0.1.0"

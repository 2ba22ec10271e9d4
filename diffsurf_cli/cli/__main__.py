"""`python -m diffsurf_cli.cli`: the command line."""
from . import main

main()

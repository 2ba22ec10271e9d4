"""`python -m diffsurf_cli`: the command line."""
from .cli import main

main()

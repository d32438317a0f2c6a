"""``python -m cam2sim``."""

from cam2sim.cli.main import main

main()

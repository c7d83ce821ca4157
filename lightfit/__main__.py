"""``python -m lightfit`` = ``lightfit`` (the command line, for environments without the console script)."""

from lightfit.cli import main

main()

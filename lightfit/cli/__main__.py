"""``python -m lightfit.cli`` = ``lightfit`` (for environments without the console script)."""

from lightfit.cli import main

main()

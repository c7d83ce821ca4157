"""``python -m lightfit.cli`` = ``python -m lightfit`` = ``lightfit`` (for environments without the console script)."""

from lightfit.cli import main

main()

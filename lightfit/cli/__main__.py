"""``python -m lightfit.cli`` = ``lightfit`` (for environments without the console script)."""

from lightfit.cli import app

app(prog_name="lightfit")

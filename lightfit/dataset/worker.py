"""Child-process entry of the data-scene renderer: ``python -m lightfit.dataset.worker JOB.npz OUT.npz``.

It exists so that a colour (``*_rgb``) render never switches the Mitsuba variant of a process
that already holds another one (see :mod:`lightfit.dataset.render`).
"""

import sys
from pathlib import Path

import lightfit  # noqa: F401 - sets DRJIT_LIBLLVM_PATH before Dr.Jit is imported
from lightfit.dataset.render import run_job

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: python -m lightfit.dataset.worker JOB.npz OUT.npz")
    run_job(Path(sys.argv[1]), Path(sys.argv[2]))

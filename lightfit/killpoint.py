"""Deterministic kill points for the resume tests (tests/test_resume.py).

Long runs promise that a process killed at any moment and rerun with the same command ends with
the uninterrupted run's result. Killing from outside at a precise moment (after a given render,
MCMC step or calibration step) is racy, so the runs call :func:`kill_point` at the moments worth
testing; with ``LIGHTFIT_TEST_KILL_AFTER="<kind>:<n>"`` in the environment the process sends
itself SIGKILL there — the same signal, without cleanup, as a user's ``kill -9``; with
``"<kind>:<n>:INT"`` it sends SIGINT, a user's Ctrl-C, which Python raises as KeyboardInterrupt;
with ``"<kind>:<n>:INT-GROUP"`` to its whole process group, as a terminal does (its workers too).

The same moments are where a Ctrl-C that CPython dropped is raised again (:func:`interrupts_kept`):
a KeyboardInterrupt raised inside a garbage-collector or weakref callback (JAX registers both; the
posterior's compile after its design runs them) is "ignored" by CPython, its traceback printed, and
the run went on to exit 0 (jax-ml/jax#18246, python/cpython#95959).
"""

from __future__ import annotations

import logging
import os
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager

#: ``"render:N"`` (after the N-th new design render is stored), ``"sample:N"`` (after MCMC step N
#: is stored, before its stop-rule check), ``"calibrate:N"`` (after accepted step N is in the
#: history, before the optimiser state is saved), ``"field-task:N"`` (after field-run's N-th task
#: is kept beside --out), ``"step:N"`` (after a run's N-th daytime step is kept,
#: :attr:`lightfit.model.coupled.CoupledModel.keep_steps`; counted from the day's first step).
KILL_HOOK = "LIGHTFIT_TEST_KILL_AFTER"


#: Set by a process that starts its own worker processes and handles Ctrl-C for them (the embedded
#: Dask cluster of ``lightfit.distributed``): its pid. Its children ignore SIGINT.
INTERRUPT_HANDLED_BY = "LIGHTFIT_INTERRUPT_HANDLED_BY"


def ignore_interrupt_in_workers() -> None:
    """In a child of a process that handles Ctrl-C for it (its pid in :data:`INTERRUPT_HANDLED_BY`),
    ignore SIGINT. A terminal's Ctrl-C reaches every process of the foreground group: the embedded
    cluster's workers printed 30–70 lines of tracebacks (interrupted imports, cancelled event loops,
    broken pipes) while the parent closed them anyway and said so in one line."""
    if os.environ.get(INTERRUPT_HANDLED_BY) == str(os.getppid()):
        try:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        except ValueError:  # not the main thread: nothing to ignore there
            pass


#: A KeyboardInterrupt that CPython reported as unraisable inside :func:`interrupts_kept`.
_dropped = False


@contextmanager
def interrupts_kept() -> Iterator[None]:
    """Within the block, a Ctrl-C that CPython would drop (raised inside a gc or weakref callback,
    module doc) is kept, without its "Exception ignored" traceback, and raised again as
    KeyboardInterrupt at the next :func:`kill_point` or when the block ends."""
    global _dropped
    previous = sys.unraisablehook

    def hook(unraisable) -> None:
        global _dropped
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            _dropped = True
        else:
            previous(unraisable)

    sys.unraisablehook, _dropped = hook, False
    callback_log = logging.getLogger(JAX_CALLBACK_LOGGER)
    callback_log.addFilter(_not_an_interrupt)
    try:
        yield
        raise_dropped_interrupt()
    finally:
        # Not left for a later kill point outside the block (another call in the same process)
        sys.unraisablehook, _dropped = previous, False
        callback_log.removeFilter(_not_an_interrupt)


#: The logger on which JAX reports a host callback's exception, with its traceback, before it
#: raises it again to the caller ("jax.pure_callback failed"; jax/_src/callback.py).
JAX_CALLBACK_LOGGER = "jax._src.callback"


def _not_an_interrupt(record: logging.LogRecord) -> bool:
    """False for a log record of a KeyboardInterrupt: the Ctrl-C is the caller's to report, once."""
    return not (record.exc_info and isinstance(record.exc_info[1], KeyboardInterrupt))


def raise_dropped_interrupt() -> None:
    """Raise KeyboardInterrupt if :func:`interrupts_kept` kept one."""
    global _dropped
    if _dropped:
        _dropped = False
        raise KeyboardInterrupt


def kill_point(kind: str, n: int) -> None:
    """Raise a Ctrl-C that CPython dropped (:func:`interrupts_kept`); then SIGKILL this process if
    :data:`KILL_HOOK` names this moment (``kind:n``), SIGINT if it names it with ``:INT``; else
    nothing."""
    raise_dropped_interrupt()
    hook = os.environ.get(KILL_HOOK, "")
    if hook == f"{kind}:{n}":
        os.kill(os.getpid(), signal.SIGKILL)
    elif hook in (f"{kind}:{n}:INT", f"{kind}:{n}:INT-GROUP"):
        # A process started by a parent that ignores SIGINT inherits SIG_IGN, and Python then
        # installs no KeyboardInterrupt handler: the simulated Ctrl-C would be lost (it was, in
        # a full pytest -n 2 run, where a worker had come to ignore SIGINT). A user's terminal
        # Ctrl-C meets Python's handler, so install it; raise_signal delivers to this thread.
        try:
            signal.signal(signal.SIGINT, signal.default_int_handler)
        except ValueError:  # not the main thread: the handler stays as it is
            pass
        if hook.endswith("GROUP"):
            # A terminal's Ctrl-C: to the whole process group, worker processes too. Only as the
            # leader of its own group (a test's start_new_session), never its caller's group.
            if os.getpgrp() != os.getpid():
                raise RuntimeError(f"{KILL_HOOK}={hook} needs a process that leads its own process group")
            os.killpg(os.getpgrp(), signal.SIGINT)
        else:
            signal.raise_signal(signal.SIGINT)

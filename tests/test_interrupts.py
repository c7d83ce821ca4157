"""Ctrl-C is never lost: one CPython drops (raised inside a gc or weakref callback) is raised again
at the next kill point or when the command ends, and one wrapped by a JAX host callback is a Ctrl-C."""

from __future__ import annotations

import gc
import re

import jax
import jax.numpy as jnp
import pytest
import typer
from typer.testing import CliRunner

from lightfit.cli.common import LightfitGroup
from lightfit.killpoint import interrupts_kept, kill_point


class _InterruptedWhileCollected:
    """Raises KeyboardInterrupt where CPython can only report it: in ``__del__`` (as in JAX's gc
    callback, where a user's Ctrl-C was lost and the run exited 0)."""

    def __del__(self):
        raise KeyboardInterrupt


def _drop_an_interrupt():
    x = _InterruptedWhileCollected()
    del x
    gc.collect()


def test_a_dropped_interrupt_is_raised_at_the_next_kill_point(capsys):
    with pytest.raises(KeyboardInterrupt), interrupts_kept():
        _drop_an_interrupt()  # CPython prints "Exception ignored" and goes on …
        kill_point("render", 1)  # … here it is raised again
    assert "Exception ignored" not in capsys.readouterr().err
    with interrupts_kept():  # kept once: a later block starts clean
        kill_point("render", 2)


def _app():
    app = typer.Typer(cls=LightfitGroup)

    @app.command()
    def dropped():
        _drop_an_interrupt()  # and no kill point after it: the command's end raises it

    @app.command()
    def wrapped():
        def render(x):
            raise KeyboardInterrupt  # Ctrl-C inside a render called from a traced loss

        f = jax.jit(lambda x: jax.pure_callback(render, jax.ShapeDtypeStruct((), jnp.float32), x))
        f(jnp.float32(1.0)).block_until_ready()

    @app.command()
    def wrapped_as_value_error():
        # What `lightfit replicate` raised at a real Ctrl-C during a render (jax 0.10's eager
        # pure_callback; a SIGINT's timing is not reproducible in a test): its text, as a ValueError.
        raise ValueError("INTERNAL: CpuCallback error calling callback: Traceback …\nKeyboardInterrupt: ")

    @app.command()
    def fails():
        f = jax.jit(lambda x: jax.pure_callback(lambda _: 1 / 0, jax.ShapeDtypeStruct((), jnp.float32), x))
        f(jnp.float32(1.0)).block_until_ready()

    return app


@pytest.mark.parametrize("command", ["dropped", "wrapped", "wrapped-as-value-error"])
def test_commands_end_interrupted_with_status_130(command):
    """Both exited as if nothing happened (0) or with ~60 lines of XLA traceback (1)."""
    r = CliRunner().invoke(_app(), [command])
    assert r.exit_code == 130, r.output
    err = re.sub(r"\x1b\[[0-9;]*m", "", r.stderr).strip()  # FORCE_COLOR in the environment colours it
    assert err.startswith("interrupted:") and len(err.splitlines()) == 1


def test_other_errors_in_a_callback_stay_errors():
    r = CliRunner().invoke(_app(), ["fails"])
    assert r.exit_code == 1 and "ZeroDivisionError" in str(r.exception)


def test_an_interrupted_command_ends_on_its_interrupt_line():
    """Cleanup that fails at exit because the run was cut short (Dask's atexit close of a cluster
    interrupted while it started: 30 lines of "AssertionError: Status.init" after the interrupt
    line) is not reported; the interrupt line is the last thing on stderr."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        """
        import atexit, logging, typer

        def cleanup():  # registered at import, as distributed registers close_clusters
            logging.getLogger("distributed").warning("worker exit status was already read")
            raise AssertionError("Status.init")

        atexit.register(cleanup)
        from lightfit.cli.common import LightfitGroup

        app = typer.Typer(cls=LightfitGroup)

        @app.command()
        def go():
            raise KeyboardInterrupt

        @app.command()
        def other():
            pass

        app(["go"])
        """
    )
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    err = re.sub(r"\x1b\[[0-9;]*m", "", p.stderr).strip()
    assert p.returncode == 130, err
    assert err.splitlines()[-1].startswith("interrupted:") and "Status.init" not in err, err

"""The shared progress display off a terminal: one whole line at the end, never cut."""

from __future__ import annotations

from lightfit.progress import progress_bar


def test_off_a_terminal_the_progress_is_one_whole_line(capsys, monkeypatch):
    """A log got rich's last live frame, cut at 80 columns ("cali… converged: projected gradient
    ∞-norm ≤ gtol 0.01; 1 steps, 3 evaluations,…"): the whole line now, with the count and info."""
    from rich import get_console

    # Off a terminal whatever the environment says (FORCE_COLOR / TTY_COMPATIBLE make rich claim one).
    monkeypatch.setattr(get_console(), "_force_terminal", False)
    info = "converged: projected gradient ∞-norm ≤ gtol 0.01; 12 steps, 31 evaluations, 31 gradients [x]"
    with progress_bar("calibrating", 30, completed=2) as bar:
        bar.update(completed=12)
        bar.update(info=info)
    out = capsys.readouterr().out
    assert out.splitlines() == [f"calibrating: 12/30 in 0 s; {info}"]
    with progress_bar("sampling", 5, show=False) as bar:
        bar.update(completed=5)
    assert capsys.readouterr().out == ""

"""Atomic writes and file kinds (lightfit.files), the cache root (lightfit.cache), figure file names
and the local-time axis (lightfit.figure)."""

from __future__ import annotations

import re
from datetime import UTC, datetime
from pathlib import Path

import h5py
import numpy as np
import pytest

from lightfit.cache import cache_root
from lightfit.errors import InputError
from lightfit.figure import clock_axis, figure_format
from lightfit.files import is_netcdf, replace_text, replaced


def test_replaced_swaps_the_whole_file_in_and_leaves_the_old_one_on_error(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text("old\n", encoding="utf-8")
    with replaced(path) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".csv" and tmp != path
        tmp.write_text("new\n", encoding="utf-8")
        assert path.read_text(encoding="utf-8") == "old\n"  # not touched before the block ends
    assert path.read_text(encoding="utf-8") == "new\n"
    with pytest.raises(RuntimeError, match="killed"):
        with replaced(path) as tmp:
            tmp.write_text("half a li", encoding="utf-8")
            raise RuntimeError("killed while writing")
    assert path.read_text(encoding="utf-8") == "new\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]  # no partial file left beside it
    with pytest.raises(RuntimeError):
        with replaced(tmp_path / "fresh.txt") as tmp:
            tmp.write_text("cut", encoding="utf-8")
            raise RuntimeError
    assert not (tmp_path / "fresh.txt").exists()
    assert replace_text(tmp_path / "u.txt", "µmol m⁻² s⁻¹") == tmp_path / "u.txt"
    assert (tmp_path / "u.txt").read_bytes() == "µmol m⁻² s⁻¹".encode()


def test_a_killed_writers_partial_file_is_removed_by_the_next_writer(tmp_path):
    """A process killed outright while writing (SIGKILL: no ``finally`` ran) leaves its temporary
    file; the next write of that file removes it. A live process's, another machine's (a shared
    folder of a distributed run) and another file's temporary files stay."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from lightfit import files

    path = tmp_path / "design [1].npz"  # glob characters in the name are the name's own
    code = (
        "import sys, time\nfrom lightfit.files import replaced\n"
        f"with replaced({str(path)!r}) as tmp:\n"
        "    tmp.write_bytes(b'half'); print(tmp.name, flush=True); time.sleep(60)\n"
    )
    writer = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    orphan = tmp_path / writer.stdout.readline().strip()
    assert orphan.exists() and orphan.name.startswith(f".partial-{files._HOST}-{writer.pid}-")
    os.kill(writer.pid, signal.SIGKILL)
    writer.wait()
    live = tmp_path / f".partial-{files._HOST}-{os.getppid()}-{path.name}"  # a live writer, not this one
    other_host = tmp_path / f".partial-elsewhere-{writer.pid}-{path.name}"
    other_file = tmp_path / f".partial-{files._HOST}-{writer.pid}-other.npz"
    for p in (live, other_host, other_file):
        p.write_bytes(b"x")
    assert orphan.exists()  # nothing cleans up after a killed writer but the next one
    replace_text(path, "whole")  # a dead writer's file changed just now: perhaps a writer it cannot see
    assert orphan.exists() and path.read_text() == "whole"
    stale = time.time() - files.ORPHAN_AGE_S - 60
    for p in (orphan, live, other_host, other_file):
        os.utime(p, (stale, stale))
    replace_text(path, "again")
    assert not orphan.exists() and path.read_text() == "again"
    assert all(p.exists() for p in (live, other_host, other_file))


def test_two_threads_writing_one_file_do_not_share_a_temporary_file(tmp_path):
    """Two threads of one process (a Dask worker with --threads-per-worker 2, both growing one plant)
    wrote the same file through one temporary file: the second to finish failed with
    FileNotFoundError, its rename's source moved by the first (a review). Each has its own now; the
    file is one writer's whole, and a dead process's thread-named file is still an orphan."""
    import os
    import threading
    import time

    from lightfit import files

    path = tmp_path / "plant.npz"
    both_written, first_done = threading.Barrier(2), threading.Event()
    errors = []

    def write(text: str, wait_for_the_other: bool) -> None:
        try:
            with replaced(path) as tmp:
                tmp.write_text(text * 1000, encoding="utf-8")
                both_written.wait(timeout=10)
                if wait_for_the_other:
                    first_done.wait(timeout=10)
            if not wait_for_the_other:
                first_done.set()
        except Exception as err:  # noqa: BLE001 - reported below
            errors.append(err)
            first_done.set()

    threads = [threading.Thread(target=write, args=(t, t == "b")) for t in "ab"]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and path.read_text(encoding="utf-8") == "b" * 1000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plant.npz"]
    dead = 2**22 + 1  # above Linux's default pid_max: no such process
    orphans = [tmp_path / f".partial-{files._HOST}-{dead}{t}-plant.npz" for t in ("-t123", "")]
    stale = time.time() - files.ORPHAN_AGE_S - 60
    for p in orphans:
        p.write_bytes(b"x")
        os.utime(p, (stale, stale))
    replace_text(path, "whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plant.npz"]


def test_netcdf_is_known_by_its_first_bytes(tmp_path):
    """netCDF-4 (an HDF5 file written by h5py), classic netCDF versions 1 and 2 (scipy's writer) and
    CDF-5 (its 4 magic bytes) are netCDF; a CSV and a short file are not."""
    from scipy.io import netcdf_file

    h5 = tmp_path / "a.nc"
    with h5py.File(h5, "w") as f:
        f["x"] = np.arange(3.0)
    assert is_netcdf(h5)
    for version in (1, 2):
        p = tmp_path / f"classic{version}.nc"
        with netcdf_file(p, "w", version=version) as f:
            f.createDimension("t", 2)
            f.createVariable("x", "d", ("t",))[:] = [1.0, 2.0]
        assert is_netcdf(p), version
    cdf5 = tmp_path / "cdf5.nc"
    cdf5.write_bytes(b"CDF\x05" + bytes(60))
    assert is_netcdf(cdf5)
    csv = tmp_path / "a.csv"
    csv.write_text("time,x\n", encoding="utf-8")
    short = tmp_path / "short.nc"
    short.write_bytes(b"CD")
    assert not is_netcdf(csv) and not is_netcdf(short)


def test_cache_root_argument_then_environment_then_home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("LIGHTFIT_CACHE", str(tmp_path / "env"))
    assert cache_root(tmp_path / "arg") == tmp_path / "arg"
    assert cache_root() == tmp_path / "env"
    monkeypatch.setenv("LIGHTFIT_CACHE", "")  # set but empty: as unset
    assert cache_root() == tmp_path / "home" / ".cache" / "lightfit"
    monkeypatch.delenv("LIGHTFIT_CACHE")
    assert cache_root() == tmp_path / "home" / ".cache" / "lightfit"


def test_figure_format_reads_the_suffix_in_any_case():
    assert figure_format("preview.PNG") == "png"
    assert figure_format(Path("out/weather.v2.Pdf")) == "pdf"
    assert figure_format("a.jpeg") == "jpeg"
    with pytest.raises(InputError, match=r"unknown image format '\.pgf'"):
        figure_format("a.pgf")
    with pytest.raises(InputError, match="no image format"):
        figure_format("preview")


def test_clock_axis_labels_the_local_time_of_the_zone():
    """12:00 UTC on 1 June 2016 is 14:00 in Berlin (CEST, UTC+2) and 08:00 in New York (EDT, UTC−4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt

    noon_utc = mdates.date2num(datetime(2016, 6, 1, 12, tzinfo=UTC))
    fig, ax = plt.subplots()
    try:
        for tz, want in (("Europe/Berlin", "14:00"), ("America/New_York", "08:00")):
            clock_axis(ax, tz)
            assert ax.xaxis.get_major_formatter()(noon_utc) == want, tz
    finally:
        plt.close(fig)


def test_the_forcing_plots_co2_axis_does_not_magnify_rounding(tmp_path, monkeypatch):
    """The bundled TERENO fixture's CO2, 400 ppm converted from mmol m⁻³ given to four decimals,
    wanders by ±0.007 ppm; the CO2 panel filled its height with it, spikes a reader takes for a
    signal (a review with the fixture as "my weather"). The axis spans at least 10 ppm; a real
    diurnal course, tens of ppm, is drawn at its own scale."""
    import matplotlib.figure
    import pandas as pd

    from lightfit.weather.plot import plot_forcing

    t = pd.date_range("2016-04-20 04:00", periods=12, freq="1h", tz="UTC")
    wobble = np.tile([-0.007, 0.005, 0.0], 4)
    df = pd.DataFrame(
        {"par_umol_m2_s": 1000.0, "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.1, "co2_ppm": 400.0 + wobble}, index=t
    )
    drawn = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: drawn.append(fig))
    for co2, span in ((400.0 + wobble, (10.0, 10.0)), (380.0 + np.linspace(0, 40, 12), (40.0, 50.0))):
        plot_forcing(df.assign(co2_ppm=co2), tmp_path / "f.png")
        lo, hi = drawn[-1].axes[2].get_ylim()
        assert span[0] <= hi - lo <= span[1] + 1e-9 and lo <= co2.min() and co2.max() <= hi, (lo, hi)
    # 04:00–15:00 UTC is 06:00–17:00 CEST on the 20th: the axis names the day (`weather show --plot`
    # of a TERENO file said "time (Europe/Berlin)" and the day nowhere in the figure)
    assert drawn[-1].axes[3].get_xlabel() == "local time (Europe/Berlin), 2016-04-20"


def _per_step_results(times_utc, **attrs):
    """The per-step variables the replication figure draws (lightfit.report.figure), made up by
    hand: a bell of PAR over the steps, no segments."""
    import pandas as pd
    import xarray as xr

    t = pd.DatetimeIndex(times_utc).tz_convert("UTC").tz_localize(None)
    par = 1500.0 * np.sin(np.linspace(0.1, np.pi - 0.1, len(t)))
    per_step = {
        "above_canopy_par_umol_m2_s": par,
        "canopy_apar_umol_m2_s": 0.9 * par,
        "plant_par_umol_m2_s": 0.2 * par,
        "plant_par_spread_umol_m2_s": 0.1 * par,
        "canopy_an_umol_m2_s": par / 50.0,
        "canopy_an_mc_sd_umol_m2_s": np.full(len(t), 0.01),
    }
    base = {"site": "Selhausen", "site_timezone": "Europe/Berlin", "n_plants": 4, "samples": 32}
    return xr.Dataset({k: ("time", v) for k, v in per_step.items()}, coords={"time": t.values}, attrs=base | attrs)


def test_the_replication_figures_title_says_an_adaptive_runs_k_range_not_its_pilot():
    """With --target-rse, --samples is each segment's pilot count and K differs per segment (up to
    the cap); the figure's title said "K=32" as for a fixed K, where summary.csv's header says the
    target and the range (a review of the main job's outputs)."""
    import matplotlib.pyplot as plt
    import pandas as pd

    from lightfit.report import figure

    t = pd.date_range("2016-04-20 06:00", periods=5, freq="2h", tz="UTC")
    for attrs, said, unsaid in (
        ({}, "4 plants, K=32", "target"),
        ({"target_rse": 0.05, "max_samples": 512}, "4 plants, target 0.05 (K from 32 to 512 per segment)", "K=32"),
    ):
        fig = figure(_per_step_results(t, **attrs))
        try:
            title = fig._suptitle.get_text()
            assert said in title and unsaid not in title, title
        finally:
            plt.close(fig)


def test_several_days_figures_name_each_days_date_on_the_time_axis(tmp_path, monkeypatch):
    """Two dates a week apart (`replicate --date` twice): the clock ticks fell on midnights and all
    read "00:00", and the replication figure's axis named the first date alone (a review of the
    main job with the bundled CPlantBox day placed on 20 and 27 April). One day keeps HH:MM."""
    import matplotlib.figure
    import matplotlib.pyplot as plt
    import pandas as pd

    from lightfit.report import figure
    from lightfit.weather.plot import plot_forcing

    one = pd.date_range("2016-04-20 04:00", periods=8, freq="2h", tz="UTC")  # 06:00–20:00 CEST
    two = one.append(one + pd.Timedelta(days=7))
    for times, date in ((one, "2016-04-20"), (two, "2016-04-20 to 2016-04-27")):
        fig = figure(_per_step_results(times))
        try:
            fig.canvas.draw()
            ax = fig.axes[2]
            assert ax.get_xlabel() == f"local time (Europe/Berlin), {date}"
            ticks = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
            if times is one:
                assert "08:00" in ticks and all(len(t) == 5 for t in ticks), ticks
            else:  # daily ticks at local midnight, with their dates
                assert "21 Apr" in ticks and len(set(ticks)) == len(ticks), ticks
            _assert_lines_stop_between_the_days(fig.axes, times)
        finally:
            plt.close(fig)
    drawn = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: drawn.append(fig))
    df = pd.DataFrame(
        {"par_umol_m2_s": 1000.0, "tair_c": 15.0, "rh": 0.6, "pair_kpa": 100.1, "co2_ppm": 400.0}, index=two
    )
    plot_forcing(df, tmp_path / "f.png")
    drawn[-1].canvas.draw()
    # every y axis names its quantity and, in parentheses, its unit: the radiation axes read
    # "PAR\nµmol m⁻² s⁻¹" and "W m⁻² (× 2.285 = PAR scale)", the right one naming no quantity
    with_split = df.assign(ghi_w_m2=437.6, dni_w_m2=300.0, dhi_w_m2=150.0)
    plot_forcing(with_split, tmp_path / "g.png")
    for ax in drawn[-1].axes:
        label = ax.get_ylabel()
        assert re.fullmatch(r"[A-Za-z][^(]*\([^()]*(µmol m⁻² s⁻¹|W m⁻²|°C|%|ppm|kPa|°)[^()]*\)", label, re.S), label
    assert [ax.get_ylabel() for ax in drawn[-1].axes][:2] == ["PAR\n(µmol m⁻² s⁻¹)", "T air (°C)"]
    assert "GHI, DHI, DNI\n(W m⁻²" in "".join(ax.get_ylabel() for ax in drawn[-1].axes)
    assert drawn[-1].axes[3].get_xlabel() == "local time (Europe/Berlin), 2016-04-20 to 2016-04-27"
    ticks = [t.get_text() for t in drawn[-1].axes[3].get_xticklabels() if t.get_text()]
    assert "21 Apr" in ticks and len(set(ticks)) == len(ticks), ticks
    _assert_lines_stop_between_the_days(drawn[-1].axes, two)


def _assert_lines_stop_between_the_days(axes, times):
    """Every curve over the steps ``times`` (8 a day) and every band: with two days, a line drawn
    from one day's last step to the next day's first slid through the nights between (a review);
    now each curve has one missing point there and each band two pieces. One day: unbroken."""
    import matplotlib.dates as mdates
    import numpy as np

    days = len(times) // 8
    curves = [ln for ax in axes for ln in ax.get_lines() if len(ln.get_xdata()) >= len(times)]
    bands = [c for ax in axes for c in ax.collections if len(c.get_paths())]
    assert len(curves) >= 3, len(curves)
    for ln in curves:
        y = np.ma.masked_invalid(np.ma.asarray(ln.get_ydata(), float))
        assert len(y) == len(times) + days - 1 and int(y.mask.sum()) == days - 1, (ln.get_label(), y)
        if days == 2:
            x = mdates.date2num(ln.get_xdata())
            gap = int(np.flatnonzero(y.mask)[0])
            assert mdates.date2num(times[7]) < x[gap] < mdates.date2num(times[8]), ln.get_label()
    for band in bands:
        assert len(band.get_paths()) == days, band.get_label()

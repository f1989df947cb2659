"""The figures of the method pages (docs/methods/figures/*.png), made from the library.

Each figure is drawn from what the code computes on the virtual conveyor
(reference profile, every realism effect on), so that it stays true of main:

* ``verification.png``: a trapezoid against the closed-loop twin, torque
  and its REP series (``chaintwin verify``);
* ``rls.png``: the viscous gear loss tracked by RLS through a 20 % step
  (``chaintwin identify --method rls``, λ = 0.98);
* ``forecast.png``: a rising friction feature, the forecast 20 recordings
  before the alarm with its 90 % band, and the limit;
* ``campbell.png``: the Campbell plot of recordings at eight speeds.

Run: ``OPENBLAS_NUM_THREADS=1 python scripts/method_figures.py [OUT_DIR]`` (about a minute).
"""

from __future__ import annotations

import base64
import sys
import tempfile
from datetime import datetime
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

sys.path.insert(0, str(Path(__file__).resolve().parent))

from forecast_coverage import degradation_run
from rls_forgetting import HOLD, recordings

from chaintwin.diagnose.forecasting import forecast_path, resample_even
from chaintwin.identify.regression import RigidModelRegression
from chaintwin.identify.tracking import track_losses
from chaintwin.identify.verification import (
    closed_loop_torque,
    twin_parameters,
    verify_recording,
)
from chaintwin.read.profile import load_profile
from chaintwin.report.figures import campbell_figure
from chaintwin.simulate import run_virtual

PROFILE = load_profile("chaintwin/examples/profiles/white-belt-01.yaml")
DPI = 96


def _save(fig: Figure, path: Path) -> None:
    FigureCanvasAgg(fig)
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=DPI)
    print(f"wrote {path}")


def verification(out: Path) -> None:
    """Measured torque against the closed-loop twin's, and the REP series."""
    rec = run_virtual(PROFILE, payload_kg=20.0, seed=11).recording
    check = verify_recording(rec, PROFILE, residual="closed-loop", payload_kg=20.0)
    model = closed_loop_torque(rec, PROFILE, twin_parameters(PROFILE), 20.0)
    fig = Figure(figsize=(9.0, 5.0))
    top, bottom = fig.add_subplot(2, 1, 1), fig.add_subplot(2, 1, 2)
    top.plot(rec.time, rec.torque, linewidth=0.6, label="measured (virtual conveyor)")
    top.plot(rec.time, model, linewidth=0.9, label="closed-loop twin (nominal parameters)")
    top.set_ylabel("motor torque [Nm]")
    top.legend(fontsize=8)
    series = check.torque.series
    if series is not None:
        bottom.plot(rec.time, series, linewidth=0.6, color="tab:red")
    whole = check.torque.whole
    title = "torque REP per sample, % of the largest |torque|"
    if whole is not None:
        title += f": mean {whole.mean_pct:.2f} %, std {whole.std_pct:.2f} %"
    bottom.set_title(title, fontsize=9)
    bottom.set_xlabel("time [s]")
    bottom.set_ylabel("REP [%]")
    _save(fig, out / "verification.png")


def rls(out: Path, n: int = 90) -> None:
    """BmB tracked by RLS (λ = 0.98) through a 20 % step, against the truth."""
    recs, b0 = recordings(n, 0)
    held = RigidModelRegression().fit(recs[:HOLD], PROFILE).parameters_
    points, _ = track_losses(recs, PROFILE, held, forgetting=0.98)
    bmb = np.array([p.values["BmB"] for p in points])
    truth = np.where(np.arange(n) < n // 2, b0, 1.2 * b0)
    fig = Figure(figsize=(9.0, 4.0))
    ax = fig.add_subplot(1, 1, 1)
    k = np.arange(n)
    ax.fill_between(k, 0.97 * truth * 1e3, 1.03 * truth * 1e3, color="0.85", label="truth ±3 %")
    ax.plot(k, truth * 1e3, color="k", linewidth=0.8, label="true BmB")
    ax.plot(k, bmb * 1e3, color="tab:blue", linewidth=1.0, label="tracked, λ = 0.98")
    ax.set_xlabel("recording")
    ax.set_ylabel("BmB [mNm·s/rad]")
    ax.set_title("viscous gear loss tracked by RLS: +20 % at the middle recording", fontsize=10)
    ax.legend(fontsize=8)
    _save(fig, out / "rls.png")


def forecast(out: Path) -> None:
    """A rising friction feature, forecast 20 recordings before the alarm, with its band."""
    with tempfile.TemporaryDirectory() as tmp:
        times, values, limit, alarm = degradation_run(1, Path(tmp))
    if alarm is None or alarm < 40:
        print("forecast: no alarm late enough to forecast before; figure not drawn")
        return
    t0 = times[0]
    days = np.array([(t - t0).total_seconds() / 86400.0 for t in times])
    vals = np.asarray(values)
    cut = alarm - 20
    ok = np.isfinite(vals[:cut])
    grid, series, step = resample_even(days[:cut][ok], vals[:cut][ok])
    steps = int(np.ceil((days[-1] - grid[-1]) / step)) + 5
    model, _mae, mean, lower, upper = forecast_path(series, steps)
    ahead = grid[-1] + step * np.arange(1, steps + 1)
    fig = Figure(figsize=(9.0, 4.0))
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(days, vals, ".", markersize=3, color="0.4", label="friction feature (monitored)")
    ax.fill_between(ahead, lower, upper, color="tab:orange", alpha=0.3, label="90 % band")
    ax.plot(ahead, mean, color="tab:orange", label=f"forecast ({model})")
    ax.axhline(limit, color="tab:red", linewidth=0.8, label="alarm limit")
    ax.axvline(days[cut - 1], color="0.5", linestyle=":", label="forecast made")
    ax.axvline(days[alarm], color="tab:red", linestyle="--", label="alarm fired")
    ax.set_xlabel(f"days since {t0:%Y-%m-%d}")
    ax.set_ylabel("μ now / μ calibrated")
    ax.set_title("remaining life: when the band reaches the limit", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    _save(fig, out / "forecast.png")


def campbell(out: Path) -> None:
    """The report's Campbell plot of recordings at eight plateau speeds."""
    speeds = np.linspace(500.0, 1500.0, 8)
    waterfall = [
        (
            f"{rpm:.0f} rpm",
            run_virtual(PROFILE, payload_kg=20.0, speed_rpm=float(rpm), seed=k).recording,
        )
        for k, rpm in enumerate(speeds)
    ]
    data = SimpleNamespace(profile=PROFILE, waterfall=waterfall)
    uri = campbell_figure(data)  # type: ignore[arg-type]
    if uri is None:
        print("campbell: nothing to draw")
        return
    path = out / "campbell.png"
    path.write_bytes(base64.b64decode(uri.split(",", 1)[1]))
    print(f"wrote {path}")


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs/methods/figures")
    out.mkdir(parents=True, exist_ok=True)
    started = datetime.now()
    verification(out)
    rls(out)
    forecast(out)
    campbell(out)
    print(f"took {(datetime.now() - started).total_seconds():.0f} s")


if __name__ == "__main__":
    main()

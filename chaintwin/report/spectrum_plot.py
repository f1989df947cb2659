"""A spectrum as a PNG picture, characteristic lines marked (matplotlib's Agg canvas)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from chaintwin.diagnose.spectra import Spectrum
from chaintwin.errors import StoreError
from chaintwin.read.files import write_atomic

__all__ = ["plot_spectrum"]


def _label_groups(lines: Mapping[str, float], x_max: float) -> list[tuple[float, str]]:
    """Lines within ``[0, x_max]``, those closer than 1 % of the range sharing one label."""
    inside = sorted((x, name) for name, x in lines.items() if 0.0 <= x <= x_max)
    groups: list[tuple[float, list[str]]] = []
    for x, name in inside:
        if groups and x - groups[-1][0] <= 0.01 * x_max:
            groups[-1][1].append(name)
        else:
            groups.append((x, [name]))
    return [(x, ", ".join(names)) for x, names in groups]


def plot_spectrum(
    spectrum: Spectrum,
    path: str | Path,
    *,
    lines: Mapping[str, float] | None = None,
    title: str | None = None,
) -> Path:
    """Write a spectrum as a PNG: log amplitude, characteristic lines marked.

    Uses the Agg canvas directly (no pyplot, no global state). The file is
    written to a temporary name beside the target and renamed, so a reader
    never sees half a file.

    Parameters
    ----------
    spectrum : Spectrum
        The spectrum.
    path : str or Path
        The PNG to write.
    lines : Mapping of str to float, optional
        Label → x position (in the spectrum's unit, e.g. apparent Hz) of
        vertical lines to draw; those outside the spectrum's range are left out.
    title : str, optional
        Plot title.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    OSError
        When the file cannot be written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    target = Path(path)
    amp = spectrum.amplitude
    positive = amp[amp > 0.0]
    floor = float(np.max(positive)) * 1e-6 if positive.size else 1e-12

    fig = Figure(figsize=(10.0, 5.0), dpi=100)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.semilogy(spectrum.x, np.maximum(amp, floor), linewidth=0.8, color="tab:blue")
    unit = "Nm" if spectrum.channel.startswith("torque") else "SI"
    ax.set_xlabel("frequency [Hz]" if spectrum.kind == "frequency" else "order [1/rev]")
    ax.set_ylabel(f"{spectrum.channel} amplitude [{unit}]")
    ax.set_xlim(float(spectrum.x[0]), float(spectrum.x[-1]))
    ax.grid(True, which="both", alpha=0.3)
    x_max = float(spectrum.x[-1])
    for position, label in _label_groups(lines or {}, x_max):
        ax.axvline(position, color="tab:red", linewidth=0.7, alpha=0.6, linestyle="--")
        ax.text(
            position,
            0.98,
            label,
            transform=ax.get_xaxis_transform(),
            rotation=90,
            va="top",
            ha="right",
            fontsize=7,
            color="tab:red",
        )
    ax.set_title(
        title or f"{spectrum.channel}, {spectrum.kind} spectrum at {spectrum.speed_rpm:.0f} rpm"
    )
    fig.tight_layout()

    return write_atomic(
        target,
        lambda tmp: fig.savefig(tmp, format="png"),
        what="picture",
        error=lambda t, m: StoreError(f"png {t}: {m}", field="png"),
    )

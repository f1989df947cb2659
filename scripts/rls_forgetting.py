"""The forgetting factor's trade-off for tracking gear losses with RLS (docs/methods/rls.md).

The virtual conveyor (reference profile, every realism switch on) runs N
recordings at three speeds and three known loads; after the first half its
viscous gear loss BmB steps up by 20 %. J_d, μ and BmC are held at a batch
least-squares fit of the first 20 recordings (before the step); BmA and BmB are tracked with
:func:`chaintwin.identify.tracking.track_losses` for several forgetting factors.

Printed per λ: the largest deviation of the tracked BmB from the truth before
the step (from recording 5 on), the number of recordings after the step until
it stays within 3 % of the new truth, and the standard deviation of the
tracked BmB over the last 20 recordings (relative to the new truth): the scatter
the forgetting factor buys the speed with.

Run: ``PYTHONPATH=. python scripts/rls_forgetting.py [N]``
"""

from __future__ import annotations

import sys

import numpy as np

from chaintwin.identify.regression import RigidModelRegression
from chaintwin.identify.tracking import track_losses
from chaintwin.read.profile import load_profile
from chaintwin.read.recording import Recording
from chaintwin.simulate import run_virtual

PROFILE_PATH = "chaintwin/examples/profiles/white-belt-01.yaml"
SPEEDS_RPM = (700.0, 1050.0, 1400.0)
LOADS_KG = (0.0, 25.0, 50.0)
STEP = 1.2
FORGETTING = (1.0, 0.995, 0.99, 0.98, 0.97, 0.95, 0.9)
HOLD = 20


def recordings(n: int, seed: int = 0) -> tuple[list[Recording], float]:
    """``n`` virtual recordings, BmB × 1.2 from the second half on; the true BmB before."""
    profile = load_profile(PROFILE_PATH)
    model = profile.model
    assert model is not None
    stepped = model.model_copy(update={"loss_viscous_nm_s_rad": model.loss_viscous_nm_s_rad * STEP})
    out = []
    for k in range(n):
        out.append(
            run_virtual(
                profile,
                payload_kg=LOADS_KG[k % 3],
                speed_rpm=SPEEDS_RPM[(k // 3) % 3],
                seed=seed + k,
                calibration=True,
                model=model if k < n // 2 else stepped,
                source=f"virtual-{k:03d}",
            ).recording
        )
    return out, model.loss_viscous_nm_s_rad


def trade_off(n: int = 90, seed: int = 0) -> list[tuple[float, float, int | None, float]]:
    """Per forgetting factor: (λ, max deviation before, recordings to settle, scatter after)."""
    profile = load_profile(PROFILE_PATH)
    recs, b0 = recordings(n, seed)
    half = n // 2
    held = RigidModelRegression().fit(recs[:HOLD], profile).parameters_
    rows = []
    for lam in FORGETTING:
        points, _ = track_losses(recs, profile, held, forgetting=lam)
        bmb = np.array([p.values["BmB"] for p in points])
        before = float(np.max(np.abs(bmb[5:half] / b0 - 1.0)))
        after = bmb[half:] / (b0 * STEP) - 1.0
        settle = next((i + 1 for i in range(after.size) if np.all(np.abs(after[i:]) <= 0.03)), None)
        late = float(np.std(after[-20:]))
        rows.append((lam, before, settle, late))
    return rows


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 90
    print(f"{n} recordings, BmB +20 % after recording {n // 2}")
    print("lambda  max dev before  recordings to 3 %  std last 20")
    for lam, before, settle, late in trade_off(n):
        s = "never" if settle is None else str(settle)
        print(f"{lam:6.3f}  {before:14.2%}  {s:>17}  {late:13.2%}")


if __name__ == "__main__":
    main()

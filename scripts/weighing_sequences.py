"""Zero-tracking sequences for the weighing evaluation (see ``evaluate_fidelity.py weighing
--sequences``).

HELD_OUT_SEED was chosen before any sequence was evaluated and is run only at the end.
"""

from __future__ import annotations

HELD_OUT_SEED = 73067
"""The sequences' held-out seed: not used while developing."""

"""Figures like the paper's Fig. 5 (identification) and Fig. 6 (validation): generalized torques of the
model Θ̂₁p₁ against the measured τ̂ − Θ̂₂p₂, per generalized coordinate, over each step's time."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .result import IdentificationResult  # noqa: E402
from .regressor import RegressorBlock  # noqa: E402
from .validation import generalized_torques  # noqa: E402

UNITS = {"alpha_l": "N m", "alpha_r": "N m", "alpha_v": "N m", "x_ch": "N", "y_ch": "N",
         "gamma_ch": "N m"}
LABELS = {"alpha_l": "α_l", "alpha_r": "α_r", "alpha_v": "α_v", "x_ch": "x_ch", "y_ch": "y_ch",
          "gamma_ch": "γ_ch"}


def torque_comparison(blocks: list[RegressorBlock], times: dict[str, np.ndarray],
                      result: IdentificationResult, path: str | Path, title: str,
                      nrmse: dict[str, float] | None = None) -> Path:
    """Plot one panel per block: measured and model generalized torque over time; save a PNG.

    Args:
        blocks: regressor blocks, each of a single channel ``"<step>/<coordinate>"``.
        times: step name → (n_rows,) time in s, aligned with that step's blocks.
        result: the identified parameters (B_w included).
        path: output PNG.
        title: figure title.
        nrmse: optional channel → NRMSE shown in the panel titles.
    """
    fig, axes = plt.subplots(len(blocks), 1, figsize=(9, 2.3 * len(blocks)), squeeze=False)
    for ax, block in zip(axes[:, 0], blocks):
        channel = str(block.channel[0])
        step, coordinate = channel.split("/")
        model, measured = generalized_torques(block, result)
        t = times[step] - times[step][0]
        ax.plot(t, measured, color="0.3", lw=0.8, label="measured τ̂ − Θ̂₂p₂")
        ax.plot(t, model, color="tab:red", lw=1.0, ls="--", label="model Θ̂₁p₁")
        extra = f"   NRMSE {100 * nrmse[channel]:.1f} %" if nrmse and channel in nrmse else ""
        ax.set_title(f"{step}: generalized torque of {LABELS.get(coordinate, coordinate)}{extra}",
                     fontsize=9, loc="left")
        ax.set_ylabel(UNITS.get(coordinate, ""))
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8, loc="upper right")
    axes[-1, 0].set_xlabel("time in step [s]")
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path

"""How a diagnosis's final fit stands against the noise, as text, for either campaign kind from
its ``--json`` object: the final RMS over the noise, why the search stopped and, under a robust
loss, where the intervals come from."""

from __future__ import annotations


def fit_lines(d: dict) -> list[str]:
    """The final RMS (``final_rms``, or the last step's) over ``noise_std`` (null: not
    declared), the ``stop_reason`` and a ``loss`` other than linear."""
    rms = d["final_rms"] if "final_rms" in d else d["steps"][-1]["rms"]
    noise = d["noise_std"]
    ratio = "noise not declared" if noise is None else f"{rms / noise:.3g}x noise"
    lines = [f"final RMS {rms:.4g} {d['unit']} ({ratio})"
             + (f"; stopped: {d['stop_reason']}" if d.get("stop_reason") else "")]
    if d.get("loss", "linear") != "linear":
        lines.append(f"loss {d['loss']} (every fit; intervals from Huber's sandwich covariance)")
    return lines

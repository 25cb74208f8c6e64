"""The model configurations compared in docs/accuracy-vs-latency.md.

Shared by the few-minute sweep (sweep.py) and the to-the-plateau partition runs
(partition_runs.py --arch), so that a name means the same network in both.
"""

from __future__ import annotations

from typing import Any

CONTRACT_WINDOW = 40  # the daemon's T (models.contract.WINDOW)
# Adam's step size by width: wide transformers want it gentler.
LEARNING_RATE = {128: 1e-3, 256: 5e-4, 512: 3e-4}

# name -> ScottiConfig fields (the rest from the paper's defaults: conv 16/32, dropout 0.1).
CONFIGS: dict[str, dict[str, Any]] = {
    "E128-L2-T40": {"embed_dim": 128, "layers": 2, "heads": 4, "head_hidden": 128},
    "E128-L2-T20": {"embed_dim": 128, "layers": 2, "heads": 4, "head_hidden": 128, "window": 20},
    "E128-L4-T40": {"embed_dim": 128, "layers": 4, "heads": 4, "head_hidden": 128},
    "E256-L2-T40": {"embed_dim": 256, "layers": 2, "heads": 4, "head_hidden": 256},
    "E256-L4-T40": {"embed_dim": 256, "layers": 4, "heads": 8, "head_hidden": 256},
    "E512-L4-T40": {"embed_dim": 512, "layers": 4, "heads": 8, "head_hidden": 256},
}
# The few-minute sweep's configs (sweep.py's default); E128-L4-T40 came later, for
# depth at the width the CPU can train to its plateau.
SWEEP_CONFIGS = ("E128-L2-T40", "E128-L2-T20", "E256-L2-T40", "E256-L4-T40", "E512-L4-T40")


def learning_rate(name: str) -> float:
    return LEARNING_RATE[CONFIGS[name]["embed_dim"]]


def window_of(name: str) -> int:
    return int(CONFIGS[name].get("window", CONTRACT_WINDOW))

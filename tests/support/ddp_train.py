"""Run by tests/test_export_distributed.py under torchrun: one rank of ``scotti train``.

``python ddp_train.py OUT_DIR TRAIN_ARGS...``: trains as ``scotti train TRAIN_ARGS``
does, then writes OUT_DIR/rank-N.json with the SHA-256 of this rank's final
weights and its step count, so the test can compare the ranks.
"""

from __future__ import annotations

import argparse
import faulthandler
import hashlib
import json
import sys
from pathlib import Path

import torch
from scotti.export import train_cli


def weights_digest(state: dict[str, torch.Tensor]) -> str:
    h = hashlib.sha256()
    for name in sorted(state):
        h.update(name.encode())
        h.update(state[name].detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def main() -> int:
    # A rank that aborts (SIGABRT) prints every thread's Python stack first, so a
    # failure in CI says where the rank was.
    faulthandler.enable()
    out, argv = Path(sys.argv[1]), sys.argv[2:]
    parser = argparse.ArgumentParser()
    train_cli.add_arguments(parser)
    trainer = train_cli.run_training(parser.parse_args(argv))
    assert trainer is not None
    report = {
        "rank": trainer.dist.rank,
        "world_size": trainer.dist.world_size,
        "sha256": weights_digest(trainer.model.state_dict()),
        "steps": trainer.state.global_step,
    }
    (out / f"rank-{trainer.dist.rank}.json").write_text(json.dumps(report))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

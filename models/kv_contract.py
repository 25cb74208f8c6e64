"""Names of the streaming-native step graph's contract (the key/value cache form).

Beside models/contract.py, which stays the paper form's contract: a graph with
``scotti.graph`` = ``step_kv`` is refused by a runtime that knows only that one.
Used by the exporter (export/kv_export.py) and the runtime (models/kv_streaming.py).
"""

from __future__ import annotations

from typing import Final

from scotti.models import contract as c

KV_GRAPH: Final = "step_kv"  # scotti.graph of the streaming-native step graph
META_STEP_KIND: Final = "scotti.step_kind"
STEP_KIND_KV: Final = "kv_cache"  # what the paper form's step graph would be: embeddings
META_KV_SLOTS: Final = "scotti.kv_slots"  # S = 2 * layers + 1 vectors of E per frame
META_RECEPTIVE_FIELD: Final = "scotti.receptive_field"  # frames one prediction reads
KV_INPUT_PAST: Final = "past_kv"  # float32 (B, T-1, S, E), oldest frame first
KV_INPUT_VALID: Final = "past_valid"  # float32 (B, T-1), 1 where the slot holds a frame
KV_OUTPUT_PRESENT: Final = "present_kv"  # float32 (B, S, E), the new frame's row
KV_STEP_INPUTS: Final = (c.STEP_INPUT_FRAME, KV_INPUT_PAST, KV_INPUT_VALID)
KV_STEP_OUTPUTS: Final = (
    c.OUTPUT_POSE,
    c.OUTPUT_ACTION_LOGITS,
    c.OUTPUT_PROGRESS,
    KV_OUTPUT_PRESENT,
    c.OUTPUT_POOLED,
)

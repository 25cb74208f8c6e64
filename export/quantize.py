"""Dynamic int8 quantization of an exported graph: MatMul/Gemm weights only.

Measured on the development machine: int8 Conv (ConvInteger) ran 2.7x slower
than fp32, so the per-frame CNN stays fp32 and only the transformer's and the
heads' matrix products are quantized.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Sequence
from pathlib import Path

import onnx
from onnxruntime.quantization import QuantType, quantize_dynamic
from scotti.export.errors import ExportError

QUANTIZED_OPS: tuple[str, ...] = ("MatMul", "Gemm")


def drop_initializer_value_info(proto: onnx.ModelProto) -> int:
    """Remove value_info entries that shadow initializers; returns how many.

    The dynamo exporter records shapes for transposed weights that the
    quantizer's shape inference then finds stale (ShapeInferenceError).
    """
    initializers = {init.name for init in proto.graph.initializer}
    keep = [vi for vi in proto.graph.value_info if vi.name not in initializers]
    dropped = len(proto.graph.value_info) - len(keep)
    del proto.graph.value_info[:]
    proto.graph.value_info.extend(keep)
    return dropped


def quantize_int8(src: Path, dst: Path, ops: Sequence[str] = QUANTIZED_OPS) -> None:
    """src (fp32 graph with metadata) -> dst (int8 ``ops``, same metadata).

    ``ops`` other than the default are for measurement (e.g. Conv too, to show
    whether it pays); ``scotti export --int8`` always uses the default.
    """
    proto = onnx.load(str(src))
    metadata = [(p.key, p.value) for p in proto.metadata_props]
    drop_initializer_value_info(proto)
    quant_log = logging.getLogger()  # the quantizer logs advice at WARNING on the root
    level = quant_log.level
    quant_log.setLevel(logging.ERROR)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            clean = Path(tmp) / "clean.onnx"
            onnx.save(proto, str(clean))
            quantize_dynamic(
                clean,
                dst,
                op_types_to_quantize=list(ops),
                weight_type=QuantType.QInt8,
            )
    except Exception as exc:  # onnxruntime raises assorted types
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        msg = f"int8 quantization of {src.name} failed: {first}"
        raise ExportError(msg) from None
    finally:
        quant_log.setLevel(level)
    out = onnx.load(str(dst))
    del out.metadata_props[:]
    for key, value in metadata:
        entry = out.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(out, str(dst))

"""Dynamic int8 quantization of an exported graph: MatMul/Gemm weights only.

Measured on the development machine: int8 Conv (ConvInteger) ran 2.7x slower
than fp32, so the per-frame CNN stays fp32 and only the transformer's and the
heads' matrix products are quantized.

``scotti export --int8`` writes the int8 copies beside a fresh export (and fits
them OOD statistics of their own with ``--calibrate``). For a model already
exported, whose checkpoint may be gone (the shipped one):

    python -m scotti.export.quantize models/scotti-default.onnx -o DIR

writes DIR/NAME.int8.onnx and DIR/NAME.int8.window.onnx from the step graph and
the window graph beside it, the metadata as they are (the fp32 model's OOD
statistics and progress calibration), the names ``scotti eval --every K``
pairs (``models.runtime.window_graph_for``).
"""

from __future__ import annotations

import argparse
import logging
import sys
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
                # 7-bit weights: on an x86 CPU without VNNI (AVX2 only) the u8 x s8
                # kernel's 16-bit sums saturate with full-range weights. On such a CPU
                # (AMD EPYC, AVX2) the tiny model's int8 pose was 17 % off its fp32
                # pose at full range and 1.4 % with this (tests/test_export_quantize.py).
                reduce_range=True,
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


def int8_copies(step: Path, out_dir: Path) -> tuple[Path, Path]:
    """int8 copies of an exported step graph and of the window graph beside it, into
    ``out_dir`` as NAME.int8.onnx and NAME.int8.window.onnx (replaced if there)."""
    name = step.name.removesuffix(".onnx")
    window = step.with_name(f"{name}.window.onnx")
    for graph in (step, window):
        if not graph.is_file():
            msg = f"{graph}: no such graph (an export writes NAME.onnx and NAME.window.onnx)"
            raise ExportError(msg)
    out_dir.mkdir(parents=True, exist_ok=True)
    copies = (out_dir / f"{name}.int8.onnx", out_dir / f"{name}.int8.window.onnx")
    for src, dst in zip((step, window), copies, strict=True):
        if dst.resolve() == src.resolve():
            msg = f"{dst}: would replace its own source"
            raise ExportError(msg)
        quantize_int8(src, dst)
    return copies


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m scotti.export.quantize",
        description="int8 copies (MatMul/Gemm weights) of an exported model's two graphs",
    )
    parser.add_argument("model", type=Path, help="the step graph, NAME.onnx")
    parser.add_argument("-o", "--out", type=Path, required=True, help="folder for the copies")
    args = parser.parse_args(argv)
    try:
        copies = int8_copies(args.model, args.out)
    except (ExportError, OSError) as exc:
        print(f"quantize: {exc}", file=sys.stderr)
        return 2
    for path in copies:
        print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

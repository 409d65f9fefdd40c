"""torch -> ONNX with the dynamo exporter, as single self-contained files."""

from __future__ import annotations

import hashlib
from pathlib import Path

import torch


def export_onnx(
    module: torch.nn.Module,
    args: tuple[torch.Tensor, ...],
    path: str | Path,
    input_names: list[str],
    output_names: list[str],
    dynamic_shapes: tuple[dict[int, torch.export.Dim], ...],
) -> Path:
    """Export `module` called on `args` to `path` (weights inside the file, opset 20)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    module.eval()
    program = torch.onnx.export(
        module,
        args,
        dynamo=True,
        input_names=input_names,
        output_names=output_names,
        dynamic_shapes=dynamic_shapes,
        opset_version=20,
        optimize=True,
        external_data=False,
    )
    if program is None:
        raise RuntimeError("the dynamo exporter returned no program")
    program.save(str(path), external_data=False)
    return path


def sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def io_spec(path: str | Path) -> dict[str, list[dict]]:
    """Inputs and outputs of an ONNX file: name, shape (-1 for dynamic axes), datatype."""
    import onnx

    model = onnx.load(str(path))
    names = {onnx.TensorProto.FLOAT: "FP32", onnx.TensorProto.INT64: "INT64", onnx.TensorProto.INT32: "INT32"}

    def spec(values) -> list[dict]:
        out = []
        for v in values:
            t = v.type.tensor_type
            shape = [d.dim_value if d.HasField("dim_value") else -1 for d in t.shape.dim]
            out.append({"name": v.name, "shape": shape, "datatype": names.get(t.elem_type, str(t.elem_type))})
        return out

    init = {i.name for i in model.graph.initializer}
    return {"inputs": spec(v for v in model.graph.input if v.name not in init), "outputs": spec(model.graph.output)}

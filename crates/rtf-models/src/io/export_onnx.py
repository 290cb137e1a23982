"""ONNX from a TorchScript module written by `rtf export` (run with the project's .venv).

usage: export_onnx.py MODULE.pt OUT.onnx C H W

The module is captured with `torch.export` (non-strict: the TorchScript interpreter's calls
are recorded at the ATen dispatcher, with dtypes and shapes, which the TorchScript-based
exporter cannot recover from a graph traced by libtorch's C++ tracer), `aten._convolution` is
rewritten to `aten.convolution` (same first nine arguments; only the latter has an ONNX
translation), and PyTorch's ONNX exporter translates the program. The module's
`extra/rtf.json` metadata (input convention, classes) goes into the model's `metadata_props`;
`onnx.checker` validates the graph, and, when onnxruntime is importable, the model runs on a
random input and is compared with the TorchScript module (max |delta| printed; above 1e-3 is
an error). OUT.onnx is complete only when this script exits 0.
"""

import json
import sys
import warnings

import torch


def main() -> int:
    module_path, out_path = sys.argv[1], sys.argv[2]
    c, h, w = (int(v) for v in sys.argv[3:6])
    # The graph executor's optimisations (constant pooling among them) compare constant
    # tensors with aten.equal on the first run, which torch.export's capture cannot evaluate
    # ("get value out of a tracing tensor"): CMX's many same-shaped weights hit it. Capture the
    # plain interpreter's calls instead.
    torch._C._set_graph_executor_optimize(False)
    extra = {"rtf.json": ""}
    module = torch.jit.load(module_path, map_location="cpu", _extra_files=extra)
    module.eval()
    meta = json.loads(extra["rtf.json"] or "{}")
    example = torch.rand(1, c, h, w)

    class Wrapper(torch.nn.Module):
        def __init__(self, inner):
            super().__init__()
            self.inner = inner

        def forward(self, x):
            return self.inner(x)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        program = torch.export.export(Wrapper(module), (example,), strict=False)
        for node in program.graph_module.graph.nodes:
            if node.op == "call_function" and node.target == torch.ops.aten._convolution.default:
                node.target = torch.ops.aten.convolution.default
                node.args = node.args[:9]
        program.graph_module.recompile()
        onnx_program = torch.onnx.export(
            program, (example,), input_names=["input"], output_names=["logits"], verbose=False
        )
        onnx_program.save(out_path)
    import onnx

    model = onnx.load(out_path)
    for key, value in meta.items():
        prop = model.metadata_props.add()
        prop.key = key
        prop.value = value if isinstance(value, str) else json.dumps(value)
    onnx.checker.check_model(model)
    onnx.save(model, out_path)
    try:
        import onnxruntime as ort
    except ImportError:
        print("onnxruntime not installed: ONNX graph checked, not run")
        return 0
    session = ort.InferenceSession(out_path, providers=["CPUExecutionProvider"])
    x = torch.rand(1, c, h, w)
    with torch.no_grad():
        expected = module(x).float().numpy()
    got = session.run(None, {"input": x.numpy()})[0]
    delta = float(abs(got - expected).max())
    print(f"onnxruntime vs TorchScript: max |delta| = {delta:.2e}")
    if delta > 1e-3:
        print(f"error: onnxruntime output differs from TorchScript by {delta}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

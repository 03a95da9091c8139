"""ONNX Runtime inference of the CenterNet detector (an optional, faster CPU backend).

The PyTorch module (:class:`~detector_node.centernet.CenterNetDetector`) stays the model: it is
what is trained, saved and loaded. For inference its dense part -- the TF.js graph up to the
head feature plus the ``heat`` and ``box`` heads -- is written as an ONNX graph with the
module's current weights (:func:`centernet_to_onnx`) and run by ONNX Runtime; the sparse part
(peaks, the orientation head at the peaks) stays in PyTorch
(:meth:`CenterNetDetector.raw_from_features`), so both backends produce the same raw output.

The ONNX graph is written op by op from the TF.js op list, not traced from PyTorch, so that
TensorFlow's semantics map onto single ONNX ops that ONNX Runtime fuses and runs in its blocked
(NCHWc) layout:

- SAME padding with an odd total (stride-2 convolutions, max pooling) becomes the operator's own
  asymmetric ``pads`` (PyTorch has no asymmetric padding: it needs a separate pad, a copy);
- legacy ``ResizeBilinear`` (no half-pixel centres, no corner alignment: output pixel i samples
  input i * in / out, clamped) is ONNX ``Resize`` linear with ``asymmetric`` coordinates;
- MobileNetV3's hard-swish is ``HardSwish``. The graph's float16 constants give it a scale of
  0.99976 (6 x fp16(1/6)), not 1; a ``Mul`` for it would split every block's blocked-layout
  run with two reorders. The scale is instead carried forward through the ops it commutes with
  (average and max pooling, ReLU, resize, products, sums and concatenations of equally scaled
  values) and folded into the weights of the next convolution; it is applied as a ``Mul`` only
  where it cannot be (a non-linearity, a sum with an unscaled value, a graph output).

Shapes are static: one graph per input size (the detector's input size is fixed per run).
Parity with the PyTorch module is tested (``tests/detector/test_onnx_backend.py``).

Needs the ``onnx`` and ``onnxruntime`` packages (installed by ``scripts/setup.sh``); without
them :func:`onnxruntime_available` is False and the detector uses PyTorch.
"""

from __future__ import annotations

import numpy as np
import torch

from . import tfjs_graph as tg
from .onnx_session import ort_session

HARD_SWISH = "HardSwish"
#: names of the ONNX graph's input and outputs
INPUT, FEATURE_OUT, DENSE_OUT = "image", "feature", "dense"


def onnxruntime_available() -> bool:
    """True when both ``onnx`` (to write the graph) and ``onnxruntime`` import."""
    try:
        import onnx  # noqa: F401
        import onnxruntime  # noqa: F401
    except ImportError:
        return False
    return True


class _Writer:
    """Collects ONNX nodes and initializers with unique names."""

    def __init__(self) -> None:
        from onnx import helper, numpy_helper

        self.helper, self.numpy_helper = helper, numpy_helper
        self.nodes: list = []
        self.inits: list = []
        self._n = 0

    def const(self, value: np.ndarray | torch.Tensor, hint: str = "c") -> str:
        arr = value.detach().cpu().numpy() if isinstance(value, torch.Tensor) else value
        self._n += 1
        name = f"{hint}__{self._n}"
        self.inits.append(self.numpy_helper.from_array(np.ascontiguousarray(arr), name))
        return name

    def op(self, op_type: str, inputs: list[str], hint: str, **attrs) -> str:
        self._n += 1
        out = f"{hint}__{self._n}"
        self.nodes.append(self.helper.make_node(op_type, inputs, [out], **attrs))
        return out


def _pads(h: int, w: int, k: tuple[int, int], s: tuple[int, int], d: tuple[int, int], same: bool):
    """ONNX pads [top, left, bottom, right] and the output size of a window op."""
    if not same:
        oh = (h - (k[0] - 1) * d[0] - 1) // s[0] + 1
        ow = (w - (k[1] - 1) * d[1] - 1) // s[1] + 1
        return [0, 0, 0, 0], (oh, ow)
    ph = tg._same_pad(h, k[0], s[0], d[0])
    pw = tg._same_pad(w, k[1], s[1], d[1])
    return [ph[0], pw[0], ph[1], pw[1]], (-(-h // s[0]), -(-w // s[1]))


def _clip6(wr: _Writer, x: str) -> str:
    """ReLU6 as an ONNX ``Clip`` to [0, 6]."""
    return wr.op("Clip", [x, wr.const(np.float32(0)), wr.const(np.float32(6))], "relu6")


class _GraphExport:
    """Writes the TF.js graph's ops as ONNX nodes, one op at a time.

    ``env`` maps a graph value name to its ONNX name and (H, W); ``pending`` holds a scalar
    factor not yet applied to a value's tensor (the hard-swish scale: see the module
    docstring)."""

    def __init__(self, g: tg.TfjsGraph, wr: _Writer) -> None:
        self.g, self.wr = g, wr
        self.scales = g._resize_scales()
        self.env: dict[str, tuple[str, tuple[int, int]]] = {}
        self.pending: dict[str, float] = {}

    def write_input(self, height: int, width: int, image_input: bool) -> None:
        """The graph input as RGB float values in [0, 255], NCHW."""
        from onnx import TensorProto

        wr = self.wr
        if image_input:
            x = wr.op("Transpose", [INPUT], "nchw", perm=[0, 3, 1, 2])
            x = wr.op("Cast", [x], "float", to=TensorProto.FLOAT)
        else:
            x = wr.op("Mul", [INPUT, wr.const(np.array(255.0, np.float32))], "scaled")
        self.env[self.g.input_name] = (x, (height, width))

    def val(self, name: str) -> tuple[str, tuple[int, int] | None]:
        g, wr = self.g, self.wr
        if name in self.env:
            return self.env[name]
        if tg._key(name) in g.params:
            return wr.const(g.params[tg._key(name)].float(), "w"), None
        if name in g.const_names:
            t = getattr(g, g.const_names[name])
            if t.dtype.is_floating_point:
                t = t.float()
            return wr.const(t, "k"), None
        raise tg.TfjsGraphError(f"node {name}: value not available")

    def hw_of(self, inputs: list[str]) -> tuple[int, int]:
        shapes = [self.env[i][1] for i in inputs if i in self.env]
        return max(shapes)

    def applied(self, name: str) -> None:
        """Apply a pending factor of ``name`` with a Mul (once: env then holds the product)."""
        if name in self.pending:
            y, hw = self.env[name]
            k = self.wr.const(np.array(self.pending.pop(name), np.float32))
            self.env[name] = (self.wr.op("Mul", [y, k], "scale"), hw)

    def common_factor(self, names: list[str]) -> float:
        """The factor pending on every one of ``names`` when they share it (constants count
        as unscaled); else applies the factors and returns 1."""
        factors = {self.pending.get(i, 1.0) for i in names}
        if len(factors) == 1:
            return factors.pop()
        for i in names:
            self.applied(i)
        return 1.0

    def carry(self, name: str, factor: float) -> None:
        if factor != 1.0:
            self.pending[name] = factor

    def write_op(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        """Write one op of the graph (``g.ops``' row)."""
        if op in tg._CONVS:
            self.conv(name, op, inputs, node)
        elif op in tg._BINARY:
            self.binary(name, op, inputs)
        elif op in self._BY_OP:
            getattr(self, self._BY_OP[op])(name, op, inputs, node)
        else:
            raise tg.TfjsGraphError(f"node {name}: op {op} not supported")

    def conv(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        g, wr = self.g, self.wr
        factor = self.pending.get(inputs[0], 1.0)  # folded into the weights below
        xin, (h, w) = self.env[inputs[0]]
        wt = g._value({}, inputs[1])
        s = tg._attr(node, "strides", [1, 1, 1, 1])[1:3]
        d = tg._attr(node, "dilations", [1, 1, 1, 1])[1:3]
        k = (int(wt.shape[2]), int(wt.shape[3]))
        padding = tg._attr(node, "padding", "VALID")
        if padding not in ("SAME", "VALID"):
            raise tg.TfjsGraphError(f"node {name}: padding {padding} not supported")
        pads, out_hw = _pads(h, w, k, tuple(s), tuple(d), padding == "SAME")
        fused = tg._attr(node, "fused_ops", []) if "Fused" in op else []
        if factor != 1.0:
            ins = [xin, wr.const(wt.float() * factor, "w")]
        else:
            ins = [xin, self.val(inputs[1])[0]]
        if fused and fused[0] == "BiasAdd":
            ins.append(self.val(inputs[2])[0])
            fused = fused[1:]
        groups = int(wt.shape[0]) if "Depthwise" in op else 1
        y = wr.op(
            "Conv",
            ins,
            "conv",
            kernel_shape=list(k),
            strides=list(s),
            dilations=list(d),
            pads=pads,
            group=groups,
        )
        for f in fused:
            if f == "Relu":
                y = wr.op("Relu", [y], "relu")
            elif f == "Relu6":
                y = _clip6(wr, y)
            else:
                raise tg.TfjsGraphError(f"node {name}: fused activation {f} not supported")
        self.env[name] = (y, out_hw)

    def hard_swish(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        self.applied(inputs[0])
        xin, hw = self.env[inputs[0]]
        if HARD_SWISH == "HardSwish":
            y = self.wr.op("HardSwish", [xin], "hswish")
        else:
            gate = self.wr.op("HardSigmoid", [xin], "hsig", alpha=1.0 / 6.0, beta=0.5)
            y = self.wr.op("Mul", [xin, gate], "hswish")
        self.env[name] = (y, hw)
        self.carry(name, float(node["scale"]))

    def hard_sigmoid(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        self.applied(inputs[0])
        xin, hw = self.env[inputs[0]]
        y = self.wr.op("HardSigmoid", [xin], "hsig", alpha=1.0 / 6.0, beta=0.5)
        self.env[name] = (y, hw)
        self.carry(name, float(node["scale"]))

    def positive_homogeneous(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        """Relu, Identity: commute with a positive factor."""
        if self.pending.get(inputs[0], 1.0) < 0:
            self.applied(inputs[0])
        xin, hw = self.env[inputs[0]]
        self.env[name] = (self.wr.op(op, [xin], op.lower()), hw)
        self.carry(name, self.pending.get(inputs[0], 1.0))

    def sigmoid(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        self.applied(inputs[0])
        xin, hw = self.env[inputs[0]]
        self.env[name] = (self.wr.op(op, [xin], op.lower()), hw)

    def relu6(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        self.applied(inputs[0])
        xin, hw = self.env[inputs[0]]
        self.env[name] = (_clip6(self.wr, xin), hw)

    def binary(self, name: str, op: str, inputs: list[str]) -> None:
        onnx_op = {"Add": "Add", "AddV2": "Add", "Sub": "Sub", "Mul": "Mul"}[op]
        if onnx_op == "Mul":
            factor = self.pending.get(inputs[0], 1.0) * self.pending.get(inputs[1], 1.0)
        else:
            factor = self.common_factor(list(inputs[:2]))
        a, b = self.val(inputs[0])[0], self.val(inputs[1])[0]
        self.env[name] = (self.wr.op(onnx_op, [a, b], onnx_op.lower()), self.hw_of(inputs))
        self.carry(name, factor)

    def mean(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        axes = sorted(int(a) % 4 for a in np.atleast_1d(self.g._value({}, inputs[1]).cpu()))
        if axes != [1, 2]:
            raise tg.TfjsGraphError(f"node {name}: Mean over axes {axes} not supported")
        xin = self.env[inputs[0]][0]
        if tg._attr(node, "keep_dims", False):  # (blocked-layout capable)
            y = self.wr.op("GlobalAveragePool", [xin], "mean")
        else:
            y = self.wr.op("ReduceMean", [xin], "mean", axes=[2, 3], keepdims=0)
        self.env[name] = (y, (1, 1))
        self.carry(name, self.pending.get(inputs[0], 1.0))

    def concat(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        axis = int(self.g._value({}, inputs[-1]))
        if axis not in (3, -1):
            raise tg.TfjsGraphError(f"node {name}: concat on axis {axis} not supported")
        factor = self.common_factor(list(inputs[:-1]))
        parts = [self.val(i)[0] for i in inputs[:-1]]
        y = self.wr.op("Concat", parts, "concat", axis=1)
        self.env[name] = (y, self.hw_of(inputs[:-1]))
        self.carry(name, factor)

    def max_pool(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        if self.pending.get(inputs[0], 1.0) < 0:
            self.applied(inputs[0])
        xin, (h, w) = self.env[inputs[0]]
        k = tg._attr(node, "ksize")[1:3]
        s = tg._attr(node, "strides")[1:3]
        same = tg._attr(node, "padding") == "SAME"
        pads, out_hw = _pads(h, w, tuple(k), tuple(s), (1, 1), same)
        y = self.wr.op("MaxPool", [xin], "maxpool", kernel_shape=k, strides=s, pads=pads)
        self.env[name] = (y, out_hw)
        self.carry(name, self.pending.get(inputs[0], 1.0))

    def resize(self, name: str, op: str, inputs: list[str], node: dict) -> None:
        if tg._attr(node, "align_corners", False) or tg._attr(node, "half_pixel_centers", False):
            raise tg.TfjsGraphError(f"node {name}: only legacy bilinear sampling supported")
        xin, (h, w) = self.env[inputs[0]]
        if name not in self.scales:
            raise tg.TfjsGraphError(f"node {name}: constant resize without an input size")
        sh, sw = self.scales[name]
        out_hw = (round(h * sh), round(w * sw))
        channels = _channels(self.g, inputs[0])
        sizes = self.wr.const(np.array([1, channels, *out_hw], np.int64), "sizes")
        y = self.wr.op(
            "Resize",
            [xin, "", "", sizes],
            "resize",
            mode="linear",
            coordinate_transformation_mode="asymmetric",
        )
        self.env[name] = (y, out_hw)
        self.carry(name, self.pending.get(inputs[0], 1.0))

    #: op -> method, for the ops other than the convolutions and the binary ops
    _BY_OP = {
        "_HardSwish": "hard_swish",
        "_HardSigmoid": "hard_sigmoid",
        "Relu": "positive_homogeneous",
        "Identity": "positive_homogeneous",
        "Sigmoid": "sigmoid",
        "Relu6": "relu6",
        "Mean": "mean",
        "ConcatV2": "concat",
        "MaxPool": "max_pool",
        "ResizeBilinear": "resize",
    }

    def feature_output(self, value: str) -> str:
        """Make graph value ``value`` (its pending factor applied) the output FEATURE_OUT, under
        that name (no copy)."""
        self.applied(value)
        feature, _ = self.env[value]
        for n in self.wr.nodes:
            n.input[:] = [FEATURE_OUT if i == feature else i for i in n.input]
            n.output[:] = [FEATURE_OUT if o == feature else o for o in n.output]
        return FEATURE_OUT


def _write_head(wr: _Writer, feature: str, head, scale) -> str:
    """A separable head (depthwise 3x3, pointwise 1x1) on ``feature``; ``scale`` (or None) is
    folded into the pointwise weights and bias."""
    dw = head.depthwise.weight
    y = wr.op(
        "Conv",
        [feature, wr.const(dw.float(), "dw")],
        "head_dw",
        kernel_shape=[3, 3],
        pads=[1, 1, 1, 1],
        group=int(dw.shape[0]),
    )
    k = scale.float() if scale is not None else 1.0
    return wr.op(
        "Conv",
        [
            y,
            wr.const(head.pointwise.weight.float() * k, "pw"),
            wr.const(head.pointwise.bias.float() * k),
        ],
        "head_pw",
        kernel_shape=[1, 1],
    )


def _serialized_model(wr: _Writer, height: int, width: int, image_input: bool) -> bytes:
    """The ONNX model of ``wr``'s nodes and initializers with the graph's input and outputs."""
    from onnx import TensorProto, helper

    gh, gw = -(-height // 4), -(-width // 4)
    if image_input:
        inp = helper.make_tensor_value_info(INPUT, TensorProto.UINT8, [1, height, width, 3])
    else:
        inp = helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, [1, 3, height, width])
    graph = helper.make_graph(
        wr.nodes,
        "centernet_dense",
        [inp],
        [
            helper.make_tensor_value_info(FEATURE_OUT, TensorProto.FLOAT, [1, 128, gh, gw]),
            helper.make_tensor_value_info(DENSE_OUT, TensorProto.FLOAT, [1, 5, gh, gw]),
        ],
        wr.inits,
    )
    m = helper.make_model(
        graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="detector_node"
    )
    m.ir_version = 8
    return m.SerializeToString()


def centernet_to_onnx(model, height: int, width: int, image_input: bool = False) -> bytes:
    """Serialized ONNX model of ``model``'s dense part at input (1, 3, height, width).

    Input ``image``: RGB in [0, 1], float32 NCHW; with ``image_input`` the image itself, RGB
    uint8 (1, height, width, 3) as the resize gives it (transposed and cast inside the graph:
    no conversion pass in Python, no scaling to [0, 1] and back). Outputs ``feature``
    (1, 128, H/4, W/4): the graph's head feature; ``dense`` (1, 5, H/4, W/4): heat logit and
    (l, t, r, b) [input px], as :meth:`CenterNetDetector.dense`. Raises
    :class:`~detector_node.tfjs_graph.TfjsGraphError` for an op it cannot write."""
    from onnx import helper

    from .centernet import FEATURE

    wr = _Writer()
    export = _GraphExport(model.graph, wr)
    export.write_input(height, width, image_input)
    for name, op, inputs, node in model.graph.ops:
        export.write_op(name, op, inputs, node)
    feature = export.feature_output(FEATURE)
    heads = [
        _write_head(wr, feature, head, scale)
        for head, scale in ((model.heat, None), (model.box, model.box_scale))
    ]
    wr.nodes.append(helper.make_node("Concat", heads, [DENSE_OUT], axis=1))
    return _serialized_model(wr, height, width, image_input)


def _channels(g: tg.TfjsGraph, name: str) -> int:
    """Channel count of a value of the graph (from the filters and concatenations before it)."""
    by_name = {o[0]: o for o in g.ops}
    memo: dict[str, int] = {}

    def ch(n: str) -> int:
        if n in memo:
            return memo[n]
        if n not in by_name:
            raise tg.TfjsGraphError(f"node {n}: channel count unknown")
        _, op, inputs, _ = by_name[n]
        if op in tg._CONVS:
            w = g._value({}, inputs[1])
            c = int(w.shape[0])
        elif op == "ConcatV2":
            c = sum(ch(i) for i in inputs[:-1])
        else:
            c = max(ch(i) for i in inputs if i in by_name)
        memo[n] = c
        return c

    return ch(name)


class OnnxCenterNet:
    """The CenterNet's dense part on ONNX Runtime, the sparse part on the PyTorch module.

    ``runner(x)`` takes (1, 3, H, W) RGB in [0, 1] (a torch tensor) and returns the raw output of
    ``model(x)``; ``runner.from_image(rgb)`` the same from a uint8 image (the detector's path).
    One ONNX Runtime session per input size, built on first use with
    ``threads`` intra-op threads (default: torch's current count, i.e. the node's
    ``num_threads``)."""

    def __init__(self, model, threads: int | None = None) -> None:
        if not onnxruntime_available():
            raise RuntimeError("onnxruntime backend: the onnx / onnxruntime packages are missing")
        self.model = model
        self.threads = threads or torch.get_num_threads()
        self._sessions: dict[tuple[int, int, bool], object] = {}

    def session(self, height: int, width: int, image_input: bool = False):
        """The session for this input size (``image_input``: uint8 HWC images, see
        :func:`centernet_to_onnx`)."""
        key = (height, width, image_input)
        if key not in self._sessions:
            graph = centernet_to_onnx(self.model, height, width, image_input)
            self._sessions[key] = ort_session(graph, self.threads)
        return self._sessions[key]

    def dense(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(feature, dense) of a (1, 3, H, W) batch, as torch tensors."""
        if x.shape[0] != 1:
            raise ValueError("onnxruntime backend: one image at a time")
        s = self.session(int(x.shape[2]), int(x.shape[3]))
        f, d = s.run(None, {INPUT: np.ascontiguousarray(x.detach().cpu().numpy(), np.float32)})
        return torch.from_numpy(f), torch.from_numpy(d)

    @torch.no_grad()
    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        f, d = self.dense(x)
        return self.model.raw_from_features(f, d)

    @torch.no_grad()
    def from_image(self, rgb: np.ndarray) -> torch.Tensor:
        """Raw output of one RGB uint8 image (H, W, 3) already at the network's input size:
        the same as ``self(to_tensor([rgb]))`` without the conversion to float in Python."""
        h, w = rgb.shape[:2]
        s = self.session(h, w, image_input=True)
        f, d = s.run(None, {INPUT: np.ascontiguousarray(rgb, np.uint8)[None]})
        return self.model.raw_from_features(torch.from_numpy(f), torch.from_numpy(d))

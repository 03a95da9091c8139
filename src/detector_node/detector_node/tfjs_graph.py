"""TF.js graph models (``model.json`` + binary weight shards) as PyTorch modules.

A TF.js graph model is a TensorFlow GraphDef in JSON (``modelTopology.node``: name, op, inputs,
attributes) plus a ``weightsManifest``: groups of binary shards (concatenated in order) holding
every ``Const`` node's value, each entry giving name, shape, dtype and an optional quantization
(here float16 stored, float32 meant). :func:`read_tfjs_model` parses both with numpy;
:class:`TfjsGraph` executes the sub-graph needed for some outputs with torch ops in NCHW layout,
the convolution filters and biases being trainable ``nn.Parameter`` objects (so the graph can be
fine-tuned), every other constant a buffer.

Supported ops (what the CenterNet / MobileNetV3 detector of ``@vladmandic/human`` uses up to its
heat-map and box outputs): Placeholder, Const, Identity, Conv2D, _FusedConv2D (fused BiasAdd and
Relu / Relu6), DepthwiseConv2dNative, FusedDepthwiseConv2dNative, Add, AddV2, Sub, Mul, Relu,
Relu6, Sigmoid, Mean (over H and W), ConcatV2 (channels), MaxPool, ResizeBilinear (legacy
TensorFlow sampling, no half-pixel centres, no corner alignment). Convolutions follow
TensorFlow's SAME padding (the extra pixel of an odd total goes after). A constant output size of
ResizeBilinear is read as the ratio to its input size at the graph's declared input size, so the
fully convolutional graph runs at any input whose sides are multiples of the network stride.
Anything else raises :class:`TfjsGraphError` naming the node.
"""

from __future__ import annotations

import base64
import json
import math
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

_DTYPES = {"float32": np.float32, "int32": np.int32, "float16": np.float16, "bool": np.bool_}


class TfjsGraphError(ValueError):
    """A TF.js graph that cannot be read or executed (names the file or node)."""


def read_tfjs_model(json_path: str | Path) -> tuple[dict, dict[str, np.ndarray]]:
    """Parse ``model.json`` and its weight shards: (model JSON, {constant name: array}).

    float16-quantized weights are returned as float32; shards are looked up beside the JSON.
    """
    json_path = Path(json_path)
    try:
        model = json.loads(json_path.read_text())
        manifest = model["weightsManifest"]
        model["modelTopology"]["node"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise TfjsGraphError(f"{json_path}: not a TF.js graph model ({exc})") from None
    weights: dict[str, np.ndarray] = {}
    for group in manifest:
        try:
            data = b"".join((json_path.parent / p).read_bytes() for p in group["paths"])
        except OSError as exc:
            raise TfjsGraphError(f"{json_path}: weight shard missing ({exc})") from None
        offset = 0
        for spec in group["weights"]:
            shape = [int(s) for s in spec["shape"]]
            count = int(np.prod(shape)) if shape else 1
            quant = spec.get("quantization")
            if quant is not None and quant.get("dtype") != "float16":
                raise TfjsGraphError(
                    f"{json_path}: {spec['name']}: quantization {quant.get('dtype')} not supported"
                )
            stored = "float16" if quant is not None else spec["dtype"]
            if stored not in _DTYPES:
                raise TfjsGraphError(f"{json_path}: {spec['name']}: dtype {stored} not supported")
            dt = np.dtype(_DTYPES[stored]).newbyteorder("<")
            nbytes = count * dt.itemsize
            if offset + nbytes > len(data):
                raise TfjsGraphError(f"{json_path}: weight data too short at {spec['name']}")
            arr = np.frombuffer(data, dtype=dt, count=count, offset=offset).reshape(shape)
            weights[spec["name"]] = arr.astype(_DTYPES[spec["dtype"]])
            offset += nbytes
        if offset != len(data):
            raise TfjsGraphError(f"{json_path}: {len(data) - offset} bytes of weights unused")
    return model, weights


def _attr(node: dict, key: str, default=None):
    """A node attribute as a plain value (list of ints, string, bool, float, int)."""
    a = node.get("attr", {}).get(key)
    if a is None:
        return default
    if "list" in a:
        lst = a["list"]
        if "i" in lst:
            return [int(v) for v in lst["i"]]
        if "s" in lst:
            return [base64.b64decode(v).decode() for v in lst["s"]]
        return []
    if "s" in a:
        return base64.b64decode(a["s"]).decode()
    if "b" in a:
        return bool(a["b"])
    if "i" in a:
        return int(a["i"])
    if "f" in a:
        return float(a["f"])
    return default


def _same_pad(size: int, k: int, stride: int, dilation: int) -> tuple[int, int]:
    """TensorFlow SAME padding (before, after) of one axis."""
    out = math.ceil(size / stride)
    total = max((out - 1) * stride + (k - 1) * dilation + 1 - size, 0)
    return total // 2, total - total // 2


def resize_bilinear_legacy(x: torch.Tensor, out_h: int, out_w: int) -> torch.Tensor:
    """TensorFlow ResizeBilinear with align_corners=False, half_pixel_centers=False: the
    output pixel i samples the input at i * in / out (clamped at the last pixel). An exact 2x
    enlargement (the case of upsampling layers) is done with slices: out[2i] = in[i],
    out[2i + 1] = (in[i] + in[i + 1]) / 2 (the last input pixel repeated)."""
    if out_h == 2 * x.shape[2] and out_w == 2 * x.shape[3]:
        return _double(_double(x, 2), 3)

    def axis(n_in: int, n_out: int):
        src = torch.arange(n_out, dtype=x.dtype, device=x.device) * (n_in / n_out)
        i0 = src.floor().long().clamp(max=n_in - 1)
        i1 = (i0 + 1).clamp(max=n_in - 1)
        return i0, i1, (src - i0.to(x.dtype))

    y0, y1, fy = axis(x.shape[2], out_h)
    x0, x1, fx = axis(x.shape[3], out_w)
    top = x[:, :, y0] * (1 - fy)[:, None] + x[:, :, y1] * fy[:, None]
    return top[..., x0] * (1 - fx) + top[..., x1] * fx


def _double(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Legacy bilinear 2x enlargement along one axis (see :func:`resize_bilinear_legacy`)."""
    nxt = torch.cat([x.narrow(dim, 1, x.shape[dim] - 1), x.narrow(dim, x.shape[dim] - 1, 1)], dim)
    shape = list(x.shape)
    shape[dim] *= 2
    return torch.stack([x, (x + nxt) * 0.5], dim + 1).reshape(shape)


_SIMPLE = {"Relu": F.relu, "Relu6": F.relu6, "Sigmoid": torch.sigmoid, "Identity": lambda t: t}
_BINARY = {"Add": torch.add, "AddV2": torch.add, "Sub": torch.sub, "Mul": torch.mul}
_CONVS = ("Conv2D", "_FusedConv2D", "DepthwiseConv2dNative", "FusedDepthwiseConv2dNative")


def _key(name: str) -> str:
    return name.replace(".", "_")


def _execution_order(nodes: dict[str, dict], outputs: list[str]) -> list[str]:
    """Names of the nodes ``outputs`` need, in execution order (depth-first, post-order)."""
    needed: list[str] = []
    seen: set[str] = set()
    for o in outputs:
        stack = [(o.split(":")[0], False)]
        while stack:
            n, done = stack.pop()
            if done:
                needed.append(n)
                continue
            if n in seen:
                continue
            if n not in nodes:
                raise TfjsGraphError(f"node {n}: referenced but not in the graph")
            seen.add(n)
            stack.append((n, True))
            for i in reversed(nodes[n].get("input", [])):
                if not i.startswith("^"):
                    stack.append((i.split(":")[0], False))
    return needed


class TfjsGraph(nn.Module):
    """Executes the part of a TF.js graph that ``outputs`` need, on NCHW tensors.

    ``forward(x)`` takes the graph's single input as (B, C, H, W) and returns {output name:
    tensor}, NCHW for 4-D results. Convolution filters are stored in PyTorch layout (O, I, kH, kW)
    as parameters named after their constant.
    """

    def __init__(self, model: dict, weights: dict[str, np.ndarray], outputs: list[str]) -> None:
        super().__init__()
        nodes = {n["name"]: n for n in model["modelTopology"]["node"]}
        needed = _execution_order(nodes, outputs)
        self.outputs = list(outputs)
        #: the graph nodes these outputs need (constants included), in execution order
        self.nodes_used = [nodes[n] for n in needed]
        self.ops: list[tuple[str, str, list[str], dict]] = []
        self.params = nn.ParameterDict()
        self.input_name = None
        self.input_hw: tuple[int, int] | None = None
        conv_args: set[str] = set()
        for name in needed:
            n = nodes[name]
            if n["op"] in _CONVS:
                conv_args.update(i.split(":")[0] for i in n["input"][1:])
        consts = self._read_nodes(nodes, needed, weights)
        self.const_names: dict[str, str] = {}
        self._store_constants(consts, conv_args)
        if self.input_name is None:
            raise TfjsGraphError("graph has no input (Placeholder) for these outputs")
        other = ("Mean", "ConcatV2", "MaxPool", "ResizeBilinear")
        for name, op, _, _ in self.ops:
            if op not in _SIMPLE and op not in _BINARY and op not in _CONVS and op not in other:
                raise TfjsGraphError(f"node {name}: op {op} not supported")
        self.fuse()

    def _read_nodes(self, nodes: dict, needed: list[str], weights) -> dict[str, np.ndarray]:
        """Sort the needed nodes: the input (``input_name``, ``input_hw``), the ops (``ops``, in
        execution order); returns the constants' values."""
        consts: dict[str, np.ndarray] = {}
        for name in needed:
            n = nodes[name]
            op = n["op"]
            if op == "Const":
                if name not in weights:
                    raise TfjsGraphError(f"node {name}: constant without weights")
                consts[name] = weights[name]
                continue
            if op == "Placeholder":
                if self.input_name is not None:
                    raise TfjsGraphError(f"node {name}: more than one graph input")
                self.input_name = name
                dims = n["attr"]["shape"]["shape"].get("dim", [])
                if len(dims) == 4:
                    self.input_hw = (int(dims[1]["size"]), int(dims[2]["size"]))
                continue
            self.ops.append((name, op, [i.split(":")[0] for i in n.get("input", [])], n))
        return consts

    def _store_constants(self, consts: dict[str, np.ndarray], conv_args: set[str]) -> None:
        """Constants: filters/biases -> parameters in torch layout, the rest -> buffers (NCHW)
        named in ``const_names``."""
        depthwise = ("DepthwiseConv2dNative", "FusedDepthwiseConv2dNative")
        depthwise_filters = {i[2][1] for i in self.ops if i[1] in depthwise}
        for name, value in consts.items():
            t = torch.from_numpy(np.ascontiguousarray(value))
            if name in conv_args and t.ndim == 4:
                if name in depthwise_filters:  # (kh, kw, C, 1) -> (C, 1, kh, kw)
                    kh, kw, c, m = t.shape
                    t = t.permute(2, 3, 0, 1).reshape(c * m, 1, kh, kw)
                else:  # (kh, kw, I, O) -> (O, I, kh, kw)
                    t = t.permute(3, 2, 0, 1)
                self.params[_key(name)] = nn.Parameter(t.contiguous().float())
            elif name in conv_args:
                self.params[_key(name)] = nn.Parameter(t.float())
            else:
                if t.ndim == 4:  # NHWC constant -> NCHW
                    t = t.permute(0, 3, 1, 2)
                elif t.ndim == 1 and t.dtype.is_floating_point and t.numel() > 1:
                    t = t.view(-1, 1, 1)
                buf = f"const_{len(self.const_names)}"
                self.register_buffer(buf, t.contiguous(), persistent=True)
                self.const_names[name] = buf

    def fuse(self) -> None:
        """Peephole fusions that read constant values (:meth:`_fuse_hard_swish`,
        :meth:`_fuse_hard_sigmoid`). Run at construction, and again after weights are loaded
        into a graph built with zero constants (a checkpoint): then the constants' values were
        not known at construction. Idempotent; the parameters are untouched."""
        self._fuse_hard_swish()
        self._fuse_hard_sigmoid()

    def _scalar(self, name: str) -> float | None:
        """Value of a scalar float constant, else None."""
        if name in self.const_names:
            t = getattr(self, self.const_names[name])
            if t.numel() == 1 and t.dtype.is_floating_point:
                return float(t)
        return None

    def _op_index(self) -> tuple[dict[str, tuple], dict[str, int]]:
        """({op name: op}, {value name: number of ops reading it})."""
        uses: dict[str, int] = {}
        for _, _, inputs, _ in self.ops:
            for i in inputs:
                uses[i] = uses.get(i, 0) + 1
        return {o[0]: o for o in self.ops}, uses

    def _binary_muls(self) -> list[tuple]:
        return [o for o in self.ops if o[1] == "Mul" and len(o[2]) == 2]

    def _fuse_hard_swish(self) -> None:
        """Peephole: ``Mul(Mul(c, x), Relu6(Add(x, 3)))`` (MobileNetV3's hard-swish, 4
        element-wise passes) -> one ``hardswish(x) * 6c`` when the intermediate results are used
        nowhere else (the outputs are never fused away)."""
        by_name, uses = self._op_index()
        dropped: set[str] = set()
        fused: dict[str, tuple] = {}
        for name, _op, inputs, _node in self._binary_muls():
            a, r = (by_name.get(i) for i in inputs)
            if a is None or r is None or a[1] != "Mul" or r[1] != "Relu6":
                a, r = r, a
            if a is None or r is None or a[1] != "Mul" or r[1] != "Relu6":
                continue
            add = by_name.get(r[2][0])
            if add is None or add[1] not in ("Add", "AddV2"):
                continue
            c = [self._scalar(i) for i in a[2]]
            x = [i for i, v in zip(a[2], c, strict=True) if v is None]
            scale = next((v for v in c if v is not None), None)
            three = [self._scalar(i) for i in add[2]]
            if scale is None or len(x) != 1 or x[0] not in add[2] or 3.0 not in three:
                continue
            inner = (a[0], r[0], add[0])
            if any(uses.get(n, 0) != 1 or n in self.outputs for n in inner):
                continue
            fused[name] = (name, "_HardSwish", [x[0]], {"scale": 6.0 * scale})
            dropped.update(inner)
        self.ops = [fused.get(o[0], o) for o in self.ops if o[0] not in dropped]

    def _fuse_hard_sigmoid(self) -> None:
        """Peephole: ``Mul(c, Relu6(Add(y, 3)))`` with c ~ 1/6 (the hard sigmoid of
        MobileNetV3's squeeze-excite gates, 3 element-wise passes) -> ``hardsigmoid(y) * 6c``
        when the intermediate results are used nowhere else."""
        by_name, uses = self._op_index()
        dropped: set[str] = set()
        fused: dict[str, tuple] = {}
        for name, _op, inputs, _node in self._binary_muls():
            c = [self._scalar(i) for i in inputs]
            r = [by_name.get(i) for i in inputs]
            j = next((k for k in (0, 1) if r[k] is not None and r[k][1] == "Relu6"), None)
            # 1/6 as stored (float16: 0.16663 -> a gate of at most 0.99976, kept exactly)
            if j is None or c[1 - j] is None or abs(6.0 * c[1 - j] - 1.0) > 1e-3:
                continue
            add = by_name.get(r[j][2][0])
            if add is None or add[1] not in ("Add", "AddV2"):
                continue
            three = [self._scalar(i) for i in add[2]]
            y = [i for i, v in zip(add[2], three, strict=True) if v is None]
            if len(y) != 1 or 3.0 not in three:
                continue
            inner = (r[j][0], add[0])
            if any(uses.get(n, 0) != 1 or n in self.outputs for n in inner):
                continue
            fused[name] = (name, "_HardSigmoid", [y[0]], {"scale": 6.0 * c[1 - j]})
            dropped.update(inner)
        self.ops = [fused.get(o[0], o) for o in self.ops if o[0] not in dropped]

    def _value(self, env: dict, name: str):
        if name in env:
            return env[name]
        if _key(name) in self.params:
            return self.params[_key(name)]
        if name in self.const_names:
            return getattr(self, self.const_names[name])
        raise TfjsGraphError(f"node {name}: value not available")

    def _conv(self, env: dict, name: str, op: str, inputs: list[str], node: dict) -> torch.Tensor:
        x = self._value(env, inputs[0])
        w = self._value(env, inputs[1])
        strides = _attr(node, "strides", [1, 1, 1, 1])
        dil = _attr(node, "dilations", [1, 1, 1, 1])
        if _attr(node, "data_format", "NHWC") != "NHWC":
            raise TfjsGraphError(f"node {name}: only NHWC graphs are supported")
        sh, sw, dh, dw = strides[1], strides[2], dil[1], dil[2]
        kh, kw = w.shape[2], w.shape[3]
        padding = _attr(node, "padding", "VALID")
        groups = x.shape[1] if "Depthwise" in op else 1
        pad: int | tuple[int, int] = 0
        if padding == "SAME":
            ph = _same_pad(x.shape[2], kh, sh, dh)
            pw = _same_pad(x.shape[3], kw, sw, dw)
            if ph[0] == ph[1] and pw[0] == pw[1]:
                pad = (ph[0], pw[0])
            else:
                x = F.pad(x, (pw[0], pw[1], ph[0], ph[1]))
        elif padding != "VALID":
            raise TfjsGraphError(f"node {name}: padding {padding} not supported")
        fused = (
            _attr(node, "fused_ops", [])
            if op.startswith("_Fused") or op.startswith("Fused")
            else []
        )
        bias = None
        if fused and fused[0] == "BiasAdd":
            bias = self._value(env, inputs[2])
            fused = fused[1:]
        elif fused:
            raise TfjsGraphError(f"node {name}: fused ops {fused} not supported")
        y = F.conv2d(x, w, bias, (sh, sw), pad, (dh, dw), groups)
        for f in fused:
            if f == "Relu":
                y = F.relu(y)
            elif f == "Relu6":
                y = F.relu6(y)
            else:
                raise TfjsGraphError(f"node {name}: fused activation {f} not supported")
        return y

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        env: dict[str, torch.Tensor] = {self.input_name: x}
        scales = self._resize_scales()  # from the constants' current values (state dict)
        for name, op, inputs, node in self.ops:
            if op in _CONVS:
                env[name] = self._conv(env, name, op, inputs, node)
            elif op == "_HardSwish":
                y = F.hardswish(self._value(env, inputs[0]))
                env[name] = y if node["scale"] == 1.0 else y * node["scale"]
            elif op == "_HardSigmoid":
                y = F.hardsigmoid(self._value(env, inputs[0]))
                env[name] = y if node["scale"] == 1.0 else y * node["scale"]
            elif op in _SIMPLE:
                env[name] = _SIMPLE[op](self._value(env, inputs[0]))
            elif op in _BINARY:
                env[name] = _BINARY[op](self._value(env, inputs[0]), self._value(env, inputs[1]))
            elif op == "Mean":
                axes = sorted(int(a) % 4 for a in np.atleast_1d(self._value(env, inputs[1]).cpu()))
                if axes != [1, 2]:
                    raise TfjsGraphError(f"node {name}: Mean over axes {axes} not supported")
                env[name] = self._value(env, inputs[0]).mean(
                    dim=(2, 3), keepdim=bool(_attr(node, "keep_dims", False))
                )
            elif op == "ConcatV2":
                axis = int(self._value(env, inputs[-1]))
                if axis not in (3, -1):
                    raise TfjsGraphError(f"node {name}: concat on axis {axis} not supported")
                env[name] = torch.cat([self._value(env, i) for i in inputs[:-1]], dim=1)
            elif op == "MaxPool":
                k, s = _attr(node, "ksize"), _attr(node, "strides")
                v = self._value(env, inputs[0])
                if _attr(node, "padding") == "SAME":
                    ph = _same_pad(v.shape[2], k[1], s[1], 1)
                    pw = _same_pad(v.shape[3], k[2], s[2], 1)
                    v = F.pad(v, (pw[0], pw[1], ph[0], ph[1]), value=float("-inf"))
                env[name] = F.max_pool2d(v, (k[1], k[2]), (s[1], s[2]))
            elif op == "ResizeBilinear":
                if _attr(node, "align_corners", False) or _attr(node, "half_pixel_centers", False):
                    raise TfjsGraphError(f"node {name}: only legacy bilinear sampling supported")
                v = self._value(env, inputs[0])
                if name not in scales:
                    raise TfjsGraphError(f"node {name}: constant resize without an input size")
                scale = scales[name]
                env[name] = resize_bilinear_legacy(
                    v,
                    round(int(v.shape[2]) * float(scale[0])),
                    round(int(v.shape[3]) * float(scale[1])),
                )
        return {o: env[o.split(":")[0]] for o in self.outputs}

    def _resize_scales(self) -> dict[str, tuple[float, float]]:
        """Propagate (H, W) through the ops at the declared input size and return, for every
        ResizeBilinear, its constant output size divided by its input size."""
        if self.input_hw is None:
            return {}
        hw: dict[str, tuple[int, int]] = {self.input_name: self.input_hw}
        scales: dict[str, tuple[float, float]] = {}
        for name, op, inputs, node in self.ops:
            shapes = [hw[i] for i in inputs if i in hw]
            if not shapes:
                continue
            h, w = shapes[0]
            if op in _CONVS or op == "MaxPool":
                s = _attr(node, "strides", [1, 1, 1, 1])
                if op == "MaxPool":
                    k = _attr(node, "ksize")[1:3]
                    d = (1, 1)
                else:
                    k = self._value({}, inputs[1]).shape[2:]
                    d = _attr(node, "dilations", [1, 1, 1, 1])[1:3]
                if _attr(node, "padding", "VALID") == "SAME":
                    hw[name] = (math.ceil(h / s[1]), math.ceil(w / s[2]))
                else:
                    hw[name] = (
                        (h - (k[0] - 1) * d[0] - 1) // s[1] + 1,
                        (w - (k[1] - 1) * d[1] - 1) // s[2] + 1,
                    )
            elif op == "Mean":
                hw[name] = (1, 1)
            elif op == "ResizeBilinear":
                size = [int(v) for v in self._value({}, inputs[1]).cpu()]
                if min(size) <= 0:
                    raise TfjsGraphError(f"node {name}: resize to {size} (weights not loaded?)")
                scales[name] = (size[0] / h, size[1] / w)
                hw[name] = (size[0], size[1])
            else:  # element-wise ops and concatenation: the largest operand (broadcasting)
                hw[name] = max(shapes)
        return scales

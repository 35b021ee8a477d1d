"""EBF's streaming step in ONNX Runtime (optional: ``pip install -e '.[onnx]'``): the centre frame of a full
window as one ONNX graph (normalisation, encoder, both LSTM layers, head, filter), run on the calling thread.

Same computation as ``stream._CentreKernel`` (and windowed mode): ONNX Runtime runs the 47 sequential LSTM steps
in native code, which saves numpy's per-call overhead of every step. ``available()`` says whether both
``onnx`` (to build the graph) and ``onnxruntime`` import; ``EBFStream`` falls back to the numpy kernel when not.
"""

from __future__ import annotations

import importlib.util

import numpy as np
import torch

from mocapnet.nn.base import NORM_KEYS
from mocapnet.nn.ebf import EBF
from mocapnet.nn.layers import dense_layers

#: ONNX's LSTM gate order is (i, o, f, c); torch's (i, f, g, o), g being ONNX's c.
_ONNX_FROM_TORCH = (0, 3, 1, 2)


def available() -> bool:
    """Whether ``onnx`` and ``onnxruntime`` can be imported."""
    return all(importlib.util.find_spec(name) is not None for name in ("onnx", "onnxruntime"))


def _lstm_params(lstm: torch.nn.LSTM, layer: int, directions: tuple[str, ...]) -> list[np.ndarray]:
    """ONNX ``W [D, 4H, in]``, ``R [D, 4H, H]``, ``B [D, 8H]`` of one layer of ``lstm`` (directions ``""``
    forward, ``"_reverse"`` backward)."""
    hid = lstm.hidden_size

    def get(name: str, sfx: str) -> np.ndarray:
        w = getattr(lstm, f"{name}_l{layer}{sfx}").detach().numpy().astype(np.float32)
        return w.reshape(4, hid, *w.shape[1:])[list(_ONNX_FROM_TORCH)].reshape(4 * hid, *w.shape[1:])

    w = np.stack([get("weight_ih", d) for d in directions])
    r = np.stack([get("weight_hh", d) for d in directions])
    b = np.stack([np.concatenate([get("bias_ih", d), get("bias_hh", d)]) for d in directions])
    return [w, r, b]


class OnnxKernel:
    """The centre frame of a full window through ONNX Runtime (one thread, the caller's): ``centre(window,
    angvel, stats)`` with scored channels ``[W, C]`` (degrees), root angular velocity ``[W, 3]`` (rad/s) and
    ``(center [C], scale [C], angvel_scale [3])`` → cleaned channels ``[C]`` (float32). A ``norm="both"``
    network's corpus statistics are constants of the graph; ``stats`` normalise its clip-normalised inputs; a
    ``sincos`` network's sine and cosine inputs are computed in the graph."""

    def __init__(self, model: EBF) -> None:
        import onnx
        import onnxruntime as ort
        from onnx import TensorProto, helper, numpy_helper

        hp = model.hparams
        lstm, half, n_ch = model.blstm.lstm, hp.half, hp.n_channels
        width, hid, n_filter = 2 * half + 1, lstm.hidden_size, model.n_filter
        nodes, inits = [], []

        def const(name: str, value: np.ndarray | float) -> str:
            arr = np.asarray(value)
            inits.append(numpy_helper.from_array(arr.astype(np.int64 if arr.dtype.kind == "i" else np.float32), name))
            return name

        def node(op: str, inputs: list[str], out: str, **attrs) -> str:
            nodes.append(helper.make_node(op, inputs, [out], **attrs))
            return out

        def dense(x: str, seq: torch.nn.Module, prefix: str) -> str:
            for i, (weight_t, bias, tanh) in enumerate(dense_layers(seq)):
                x = node("MatMul", [x, const(f"{prefix}{i}_w", weight_t)], f"{prefix}{i}_mm")
                x = node("Add", [x, const(f"{prefix}{i}_b", bias)], f"{prefix}{i}_add")
                if tanh:
                    x = node("Tanh", [x], f"{prefix}{i}_tanh")
            return x

        def normalised(center: str, scale: str, angvel_scale: str, p: str) -> list[str]:
            """``base.normalise`` and ``angvel_features`` of the window: wrap(x - center) / scale and angvel /
            angvel_scale, clipped at ±8 (``p``: prefix of the node names)."""
            d = node("Add", [node("Sub", ["window", center], f"{p}d0"), "c180"], f"{p}d1")
            d = node(
                "Sub",
                [d, node("Mul", [node("Floor", [node("Div", [d, "c360"], f"{p}d2")], f"{p}d3"), "c360"], f"{p}d4")],
                f"{p}d5",
            )
            x = node("Div", [node("Sub", [d, "c180"], f"{p}d6"), scale], f"{p}x0")
            x = node("Clip", [x, "lo", "hi"], f"{p}x1")
            return [x, node("Clip", [node("Div", ["angvel", angvel_scale], f"{p}w0"), "lo", "hi"], f"{p}w1")]

        for name, value in (("c180", 180.0), ("c360", 360.0), ("lo", -8.0), ("hi", 8.0)):
            const(name, value)
        # base.input_features: the window normalised with the given statistics, after the same with the
        # corpus buffers for norm="both"
        features = normalised("center", "scale", "angvel_scale", "")
        if hp.get("norm", "corpus") == "both":
            corpus = [const(f"corpus_{key}", getattr(model, key).numpy()) for key in NORM_KEYS]
            features = normalised(*corpus, "corpus_") + features
        if hp.get("sincos", False):
            rad = node("Mul", ["window", const("deg2rad", np.pi / 180.0)], "rad")
            features += [node("Sin", [rad], "sin"), node("Cos", [rad], "cos")]
        code = dense(node("Concat", features, "feat", axis=1), model.encoder, "enc")
        code = node("Unsqueeze", [code, const("ax1", np.array([1]))], "code")  # [W, 1, F]
        names = [const(f"l0_{k}", v) for k, v in zip("wrb", _lstm_params(lstm, 0, ("", "_reverse")))]
        y = node("LSTM", [code, *names], "y1", hidden_size=hid, direction="bidirectional")  # [W, 2, 1, H]
        y = node(
            "Reshape",
            [node("Transpose", [y], "y1t", perm=[0, 2, 1, 3]), const("shp", np.array([width, 1, 2 * hid]))],
            "y1r",
        )
        last = []
        for k, (sfx, direction, lo, hi) in enumerate(
            (("", "forward", 0, half + 1), ("_reverse", "reverse", half, width))
        ):
            part = node("Slice", [y, const(f"s{k}", np.array([lo])), const(f"e{k}", np.array([hi]))], f"part{k}")
            params = [const(f"l1{k}_{n}", v) for n, v in zip("wrb", _lstm_params(lstm, 1, (sfx,)))]
            nodes.append(helper.make_node("LSTM", [part, *params], ["", f"h{k}"], hidden_size=hid, direction=direction))
            last.append(f"h{k}")
        hidden = node(
            "Reshape", [node("Concat", last, "hcat", axis=2), const("shp2", np.array([1, 2 * hid]))], "hidden"
        )
        params = dense(hidden, model.head, "head")  # [1, P]
        raw = node("Slice", [params, const("f0", np.array([0])), const("f1", np.array([n_filter])), "ax1"], "raw")
        if hp.filter_shape == "free":
            logits = node("Reshape", [raw, const("shp3", np.array([n_ch, width]))], "logits")
        else:
            taps = -0.5 * np.arange(-half, half + 1, dtype=np.float32) ** 2
            sig = node(
                "Exp",
                [
                    node(
                        "Mul", [node("Clip", [raw, const("m5", -5.0), const("p5", 5.0)], "rc"), const("m2", -2.0)], "r2"
                    )
                ],
                "inv_var",
            )
            logits = node(
                "Mul", [node("Transpose", [sig], "inv_var_t", perm=[1, 0]), const("taps", taps[None])], "logits"
            )
        weights = node("Softmax", [logits], "weights", axis=1)  # [C, K]
        out = node(
            "ReduceSum",
            [node("Mul", [weights, node("Transpose", ["window"], "win_t", perm=[1, 0])], "wx"), "ax1"],
            "filtered",
            keepdims=0,
        )
        if hp.bias:
            bound = float(hp.get("bias_bound", 3.0))
            raw_b = node("Slice", [params, "f1", const("f2", np.array([n_filter + n_ch])), "ax1"], "raw_b")
            shift = node(
                "Mul", [node("Tanh", [node("Div", [raw_b, const("bound", bound)], "rb")], "tb"), "bound"], "sb"
            )
            out = node(
                "Sub",
                [
                    out,
                    node(
                        "Reshape", [node("Mul", [shift, "scale"], "shift"), const("shp4", np.array([n_ch]))], "shift_c"
                    ),
                ],
                "debiased",
            )
        nodes.append(helper.make_node("Identity", [out], ["values"]))
        f32 = TensorProto.FLOAT
        graph = helper.make_graph(
            nodes,
            "ebf_centre",
            [
                helper.make_tensor_value_info("window", f32, [width, n_ch]),
                helper.make_tensor_value_info("angvel", f32, [width, 3]),
                helper.make_tensor_value_info("center", f32, [n_ch]),
                helper.make_tensor_value_info("scale", f32, [n_ch]),
                helper.make_tensor_value_info("angvel_scale", f32, [3]),
            ],
            [helper.make_tensor_value_info("values", f32, [n_ch])],
            inits,
        )
        proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
        onnx.checker.check_model(proto)
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = 1
        options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        self._session = ort.InferenceSession(proto.SerializeToString(), options, providers=["CPUExecutionProvider"])

    def centre(
        self, window: np.ndarray, angvel: np.ndarray, stats: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> np.ndarray:
        """Cleaned scored channels ``[C]`` of the centre frame of ``window [W, C]`` (see the class)."""
        center, scale, angvel_scale = stats
        feed = {"window": window, "angvel": angvel, "center": center, "scale": scale, "angvel_scale": angvel_scale}
        return self._session.run(None, feed)[0]

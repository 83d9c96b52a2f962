#!/usr/bin/env python3
"""Writes the VGG reference fixtures under tests/fixtures/vgg/, using onnxruntime as the
independent implementation the Rust importer is tested against.

  python3 scripts/make_vgg_fixture.py [--real PATH_TO_VGG16.onnx]

Outputs:
  tiny_nhwc.onnx, tiny_nchw.onnx   small VGG-shaped graphs (10 convs, pools after 2, 4, 7) with
                                   random weights, in the tf2onnx (NHWC + Transpose) and the
                                   torchvision (NCHW) layouts
  too_few.onnx                     6 convolutions only (must be refused)
  input.npy                        a 1x3x24x24 RGB image in [0,1] (NCHW)
  tiny_<layout>_<layer>.npy        onnxruntime's activations at relu1_2/2_2/3_3/4_3 for input.npy
                                   after the layout's preprocessing (nhwc: caffe, nchw: torch)
  real_input.npy, real_<layer>.npy the same for the real VGG-16 (when --real is given), 32x32
Needs: pip install onnx onnxruntime numpy
"""
import argparse
import os

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

OUT = os.path.join(os.path.dirname(__file__), "..", "tests", "fixtures", "vgg")
LAYERS = ["relu1_2", "relu2_2", "relu3_3", "relu4_3"]
TINY = [4, 4, 8, 8, 8, 8, 8, 8, 8, 8]


def caffe(rgb):
    bgr = rgb[:, ::-1] * 255.0
    return bgr - np.array([103.939, 116.779, 123.68], np.float32).reshape(1, 3, 1, 1)


def torch(rgb):
    mean = np.array([0.485, 0.456, 0.406], np.float32).reshape(1, 3, 1, 1)
    std = np.array([0.229, 0.224, 0.225], np.float32).reshape(1, 3, 1, 1)
    return (rgb - mean) / std


def build(channels, nhwc, n_convs=10, seed=0):
    rng = np.random.default_rng(seed)
    nodes, inits = [], []
    x = "input"
    if nhwc:
        nodes.append(helper.make_node("Transpose", ["input"], ["x_nchw"], perm=[0, 3, 1, 2]))
        x = "x_nchw"
    c_in = 3
    relu_names = {}
    for i in range(n_convs):
        c_out = channels[i]
        w = (rng.standard_normal((c_out, c_in, 3, 3)) * np.sqrt(2.0 / (9 * c_in))).astype(np.float32)
        b = (rng.standard_normal(c_out) * 0.1).astype(np.float32)
        inits += [numpy_helper.from_array(w, f"w{i}"), numpy_helper.from_array(b, f"b{i}")]
        nodes.append(helper.make_node("Conv", [x, f"w{i}", f"b{i}"], [f"c{i}"], kernel_shape=[3, 3], pads=[1, 1, 1, 1], strides=[1, 1]))
        nodes.append(helper.make_node("Relu", [f"c{i}"], [f"r{i}"]))
        x = f"r{i}"
        relu_names[i + 1] = x
        if i + 1 in (2, 4, 7):
            nodes.append(helper.make_node("MaxPool", [x], [f"p{i}"], kernel_shape=[2, 2], strides=[2, 2]))
            x = f"p{i}"
        c_in = c_out
    shape = [1, None, None, 3] if nhwc else [1, 3, None, None]
    inp = helper.make_tensor_value_info("input", TensorProto.FLOAT, shape)
    outs = [helper.make_tensor_value_info(x, TensorProto.FLOAT, None)]
    for idx in (2, 4, 7, 10):
        if idx in relu_names and relu_names[idx] != x:
            outs.append(helper.make_tensor_value_info(relu_names[idx], TensorProto.FLOAT, None))
    g = helper.make_graph(nodes, "vgg_like", [inp], outs, inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 13)], producer_name="ins-rs-fixture")
    m.ir_version = 8
    return m, relu_names


def run(model, feed):
    sess = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    return dict(zip(names, sess.run(None, {"input": feed})))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--real")
    args = ap.parse_args()
    os.makedirs(OUT, exist_ok=True)
    h = w = 24
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    rgb = np.stack([(np.sin(xx / 3.0) + 1) / 2, (np.cos(yy / 4.0) + 1) / 2, ((xx + yy) % 7) / 6.0])[None].astype(np.float32)
    np.save(os.path.join(OUT, "input.npy"), rgb)
    for layout, nhwc, pre in (("nhwc", True, caffe), ("nchw", False, torch)):
        m, relus = build(TINY, nhwc, seed=1 if nhwc else 2)
        onnx.save(m, os.path.join(OUT, f"tiny_{layout}.onnx"))
        x = pre(rgb).astype(np.float32)
        feed = np.ascontiguousarray(x.transpose(0, 2, 3, 1)) if nhwc else x
        res = run(m, feed)
        # relu1_2, relu2_2, relu3_3 come before their pools; relu4_3 is the last output.
        for name, idx in zip(LAYERS, (2, 4, 7, 10)):
            np.save(os.path.join(OUT, f"tiny_{layout}_{name}.npy"), res[relus[idx]])
    m, _ = build(TINY, False, n_convs=6, seed=3)
    onnx.save(m, os.path.join(OUT, "too_few.onnx"))
    if args.real:
        real = onnx.load(args.real)
        # Expose the four ReLU outputs by their Keras layer names.
        keras = {"relu1_2": "block1_conv2", "relu2_2": "block2_conv2", "relu3_3": "block3_conv3", "relu4_3": "block4_conv3"}
        found = {}
        for n in real.graph.node:
            for k, v in keras.items():
                if n.op_type == "Relu" and f"/{v}_1/" in n.name:
                    found[k] = n.output[0]
        # Keep the graph up to relu4_3 (the classifier head fixes the input to 240x240) and
        # let the spatial size vary.
        g = real.graph
        last = next(i for i, n in enumerate(g.node) if found["relu4_3"] in n.output)
        keep = list(g.node[: last + 1])
        del g.node[:]
        g.node.extend(keep)
        del g.output[:]
        for k in LAYERS:
            g.output.append(helper.make_tensor_value_info(found[k], TensorProto.FLOAT, None))
        del g.value_info[:]
        for d, name in zip(real.graph.input[0].type.tensor_type.shape.dim[1:3], ("h", "w")):
            d.ClearField("dim_value")
            d.dim_param = name
        s = 32
        yy, xx = np.mgrid[0:s, 0:s].astype(np.float32)
        img = np.stack([(np.sin(xx / 5.0) + 1) / 2, (np.cos(yy / 3.0) + 1) / 2, ((xx * yy) % 11) / 10.0])[None].astype(np.float32)
        np.save(os.path.join(OUT, "real_input.npy"), img)
        feed = np.ascontiguousarray(caffe(img).astype(np.float32).transpose(0, 2, 3, 1))
        sess = ort.InferenceSession(real.SerializeToString(), providers=["CPUExecutionProvider"])
        names = [o.name for o in sess.get_outputs()]
        res = dict(zip(names, sess.run(None, {real.graph.input[0].name: feed})))
        for k in LAYERS:
            np.save(os.path.join(OUT, f"real_{k}.npy"), res[found[k]].astype(np.float32))
    print("fixtures written to", os.path.abspath(OUT))


if __name__ == "__main__":
    main()

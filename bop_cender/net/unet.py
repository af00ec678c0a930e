"""Stage 1's network: a small U-Net with a shared backbone and two heads (paper Section 2.1, appendix).

One fully convolutional network turns a view into center logits ``(C, H, W)`` (one shared channel for
DIMO, one per object id for T-LESS) and curvature logits ``(1, H, W)``; both are trained with
BCE-with-logits and turned into probabilities with a sigmoid at inference.

Architecture (the appendix's feature-map tables, read as a three-level U-Net):

- encoder: three levels ``e1, e2, e3`` of ``channels[i]`` features, each entered by a strided
  convolution of stride ``strides[i]`` (DIMO ``(1, 2, 2)``: full, 1/2, 1/4 resolution; T-LESS
  ``(3, 1, 3)``: 1/3, 1/3, 1/9), then a bottleneck at the last level;
- decoder: upsample to the previous level, concatenate its features (the tables' ``64 + 32``), convolve;
  twice, ending at ``e1``'s resolution with ``channels[2]`` features;
- heads: two separate branches of two 3x3 convolutions of ``head_channels`` and a 1x1 output
  convolution; where ``e1`` is below full resolution (a first stride above 1) the logits are upsampled
  bilinearly to the input size.

Optionally (``context_dilations``, ours), residual dilated 3x3 convolutions after the bottleneck widen the
receptive field at the coarsest level for almost no cost: the lean DIMO network sees about 107 px (in theory,
far less in effect), while a 144 mm shaft or an L-bracket whose box centre lies beside the metal spans about
100 px of a 320x256 DIMO view, and its centre can only be placed from both ends. Dilations (2, 4, 8) at 1/8
resolution add 2 x 8 x (2 + 4 + 8) = 224 px.

Every block is 3x3 conv, BatchNorm, ReLU, twice. Inputs of any size are padded (replicate) at the
bottom and right to a multiple of the total stride and the outputs cropped back.

Variants: :meth:`UNetSpec.dimo` (paper, 320x256, 32/32/64 with heads of 32), :meth:`UNetSpec.tless`
(paper, 720x540, 64/128/256, heads of 128, first stride 3), :meth:`UNetSpec.dimo_lean`, ours for DIMO on
2 CPU cores: a first stride of 2 (every feature at half resolution or less) and fewer channels, about 15x
cheaper than the paper's (see ``results/bench/``), :meth:`UNetSpec.dimo_context`, the lean one with
the dilated context blocks above, :meth:`UNetSpec.dimo_refine`, that one with a full-resolution curvature
refinement (``refine_channels``), :meth:`UNetSpec.tless_factored`, ours for T-LESS: factored centers
(:func:`factored_center_logits`) and context blocks, and :meth:`UNetSpec.tless_refine`, that one with the refinement.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import torch
import torch.nn.functional as F
from torch import nn

from bop_cender.net.votes import VOTE_CHANNELS, vote_map

#: The vote blur's standard deviation, pixels: below 0.1 the blur is a bare splat (its kernel underflows to NaN
#: below ~1e-23), above 100 it covers several parts and costs ~1 s per view (its radius is 3 sigma).
VOTE_SIGMA_RANGE_PX = (0.1, 100.0)
#: How a vote map joins the center head's (:attr:`UNetSpec.vote_mix`).
VOTE_MIXES = ("max", "votes")


@dataclass(frozen=True)
class UNetSpec:
    """What a :class:`UNet` is made of; saved in every checkpoint, so weights are rebuilt exactly.

    Attributes:
        channels: features of the three encoder levels (before ``width``).
        strides: downsampling factor entering each level (the total stride is their product).
        head_channels: features of each head's two 3x3 convolutions (before ``width``).
        center_channels: center output channels: 1 (shared, DIMO) or one per object id (T-LESS: 30).
        width: multiplier of every feature count (rounded, at least 4).
        name: the variant's name, for cards and messages.
        context_dilations: dilations of residual 3x3 convolutions after the bottleneck (empty: none, the
            paper's network); weights files written before this field existed have none.
        factored_centers: with several center channels, the center head predicts one class-agnostic center
            logit and ``center_channels`` class logits, and channel ``k``'s probability is
            ``sigmoid(center) * softmax(classes)_k`` (ours, see :func:`factored_center_logits`); False: one
            independent logit per channel (the paper's). Weights files written before this field have False.
        refine_channels: features of a full-resolution curvature refinement (ours; 0: none, the paper's). With a
            first stride above 1 the heads run below full resolution and their upsampled logits cannot draw a
            1-pixel edge: the GT curvature of DIMO test views, averaged over 2x2 pixels and upsampled back, has
            curvature AP 0.735 (``results/net/dimo.md``). The refinement convolves the input at full resolution,
            joins it to the curvature head's upsampled features and logit, and adds a correction to the logit
            (:class:`_Refine`). Needs a first stride above 1. Weights files written before this field have 0.
        center_branch_channels: features of a centre-only branch (ours; 0: none, the paper's): the bottleneck's
            features joined with the decoder's quarter-resolution ones, a block and residual dilated convolutions
            (dilations 1, 2, 4, 8) at the bottleneck's resolution, added to the center head's input
            (:class:`_CenterBranch`). Why: the shared decoder serves both heads, and the centre of a long or
            L-shaped part (its bounding-box centre off the metal) must be placed from the shape of the whole part;
            the branch gives the centres capacity and context of their own, and, trained alone
            (``--train-only center_branch,center_head``), leaves the curvature bit for bit. It starts as the
            identity (its output convolution is zero), so weights without it start it. Weights files written
            before this field have 0.
        center_votes: a vote head (ours; False: none, the paper's): per pixel, whether it shows a target object,
            the offset to that object's centre and its visible area; their votes make a class-agnostic center map
            (:mod:`bop_cender.net.votes`: the bounding-box centre of an L-shaped bracket lies in the air, where the
            center head finds nothing to fire on). Weights without it start it (the head is new, the rest as was).
        vote_sigma_px: the standard deviation (pixels of the input) of the Gaussian that blurs the votes.
        vote_mix: how the votes' map joins the center head's class-agnostic map: ``max`` (their maximum: the head
            keeps the parts whose centre it finds, the votes add the others) or ``votes`` (the votes alone).
    """

    channels: tuple[int, int, int] = (32, 32, 64)
    strides: tuple[int, int, int] = (1, 2, 2)
    head_channels: int = 32
    center_channels: int = 1
    width: float = 1.0
    name: str = "dimo"
    context_dilations: tuple[int, ...] = ()
    factored_centers: bool = False
    refine_channels: int = 0
    center_branch_channels: int = 0
    center_votes: bool = False
    vote_sigma_px: float = 3.0
    vote_mix: str = "max"

    def __post_init__(self) -> None:
        if len(self.channels) != 3 or len(self.strides) != 3:
            raise ValueError(f"channels and strides need 3 levels, got {self.channels} and {self.strides}")
        if min(self.channels) < 1 or min(self.strides) < 1 or self.head_channels < 1 or self.center_channels < 1:
            raise ValueError(f"channels, strides, head channels and center channels must be >= 1: {self}")
        if not self.width > 0:
            raise ValueError(f"width must be > 0, got {self.width}")
        if any(d < 1 for d in self.context_dilations):
            raise ValueError(f"context dilations must be >= 1, got {self.context_dilations}")
        if self.factored_centers and self.center_channels < 2:
            raise ValueError("factored centers need at least 2 center channels (one per object id)")
        if self.refine_channels < 0:
            raise ValueError(f"refine channels must be >= 0, got {self.refine_channels}")
        if self.center_branch_channels < 0:
            raise ValueError(f"center branch channels must be >= 0, got {self.center_branch_channels}")
        if not (VOTE_SIGMA_RANGE_PX[0] <= self.vote_sigma_px <= VOTE_SIGMA_RANGE_PX[1]):  # NaN fails too
            lo, hi = VOTE_SIGMA_RANGE_PX
            raise ValueError(f"vote sigma must be {lo:g} to {hi:g} pixels, got {self.vote_sigma_px}")
        if self.vote_mix not in VOTE_MIXES:
            raise ValueError(f"vote mix must be one of {', '.join(VOTE_MIXES)}, got {self.vote_mix!r}")
        if self.refine_channels and self.strides[0] == 1:
            raise ValueError(
                "a full-resolution refinement needs a first stride above 1 (the heads are at full resolution)"
            )

    @staticmethod
    def dimo(width: float = 1.0) -> UNetSpec:
        """The paper's DIMO model (appendix table): 32/32/64 at full, 1/2, 1/4 resolution, heads of 32."""
        return UNetSpec((32, 32, 64), (1, 2, 2), 32, 1, width, "dimo")

    @staticmethod
    def tless(center_channels: int = 30, width: float = 1.0) -> UNetSpec:
        """The paper's T-LESS model: 64/128/256 at 1/3, 1/3, 1/9 resolution (first stride 3), heads of 128."""
        return UNetSpec((64, 128, 256), (3, 1, 3), 128, center_channels, width, "tless")

    @staticmethod
    def dimo_lean(width: float = 1.0) -> UNetSpec:
        """Ours for 2 CPU cores: first stride 2, 16/24/32 at 1/2, 1/4, 1/8 resolution, heads of 16 (1.0 GMAC a view,
        the paper's 15.8)."""
        return UNetSpec((16, 24, 32), (2, 2, 2), 16, 1, width, "dimo-lean")

    @staticmethod
    def dimo_context(width: float = 1.0) -> UNetSpec:
        """:meth:`dimo_lean` with residual context convolutions of dilations 2, 4, 8 after the bottleneck (1/8
        resolution): a receptive field of about 330 px instead of 107, for 4 % more MACs (1.07 against 1.03 GMAC per 320x256 view)."""
        return UNetSpec((16, 24, 32), (2, 2, 2), 16, 1, width, "dimo-context", (2, 4, 8))

    @staticmethod
    def dimo_refine(width: float = 1.0) -> UNetSpec:
        """:meth:`dimo_context` with a full-resolution curvature refinement of 8 features (:class:`_Refine`; 1.20
        against 1.07 GMAC per 320x256 view); it starts as the identity, so ``dimo-context`` weights start it."""
        return replace(UNetSpec.dimo_context(width), name="dimo-refine", refine_channels=8)

    @staticmethod
    def dimo_centers(width: float = 1.0) -> UNetSpec:
        """:meth:`dimo_context` with a centre-only branch of 48 features at 1/8 resolution (:class:`_CenterBranch`;
        1.24 against 1.07 GMAC per 320x256 view, ``python scripts/bench_net.py --variants dimo-context,dimo-centers``);
        it starts as the identity, so ``dimo-context`` weights start it."""
        return replace(UNetSpec.dimo_context(width), name="dimo-centers", center_branch_channels=48)

    @staticmethod
    def dimo_votes(width: float = 1.0) -> UNetSpec:
        """:meth:`dimo_context` with centre votes (:mod:`bop_cender.net.votes`), blurred by 2 px (DIMO's centre blobs:
        sigma 2-5 px at 320x256); ``dimo-context`` weights start it."""
        return replace(UNetSpec.dimo_context(width), name="dimo-votes", center_votes=True, vote_sigma_px=2.0)

    @staticmethod
    def tless_lean(center_channels: int = 30, width: float = 1.0) -> UNetSpec:
        """Ours for 2 CPU cores on 720x540: first stride 3, 16/32/48 at 1/3, 1/6, 1/12, heads of 32."""
        return UNetSpec((16, 32, 48), (3, 2, 2), 32, center_channels, width, "tless-lean")

    @staticmethod
    def tless_factored(center_channels: int = 30, width: float = 1.0) -> UNetSpec:
        """:meth:`tless_lean` with factored centers (one class-agnostic center map times a per-pixel object class)
        and context convolutions of dilations 2, 4, 8 at 1/12 resolution (the whole view: an object's id comes
        from its size, and its size in pixels from the pile around it)."""
        return UNetSpec((16, 32, 48), (3, 2, 2), 32, center_channels, width, "tless-factored", (2, 4, 8), True)

    @staticmethod
    def tless_refine(center_channels: int = 30, width: float = 1.0) -> UNetSpec:
        """:meth:`tless_factored` with a full-resolution curvature refinement of 8 features (:class:`_Refine`): its
        heads run at 1/3 resolution, where the GT curvature averaged over 3x3 pixels and upsampled back has curvature
        AP 0.62; ``tless-factored`` weights start it."""
        return replace(UNetSpec.tless_factored(center_channels, width), name="tless-refine", refine_channels=8)

    @staticmethod
    def tless_votes(center_channels: int = 30, width: float = 1.0) -> UNetSpec:
        """:meth:`tless_factored` with centre votes (:mod:`bop_cender.net.votes`) for its class-agnostic map, blurred by
        4 px (T-LESS's centre blobs: sigma 10-20 px at 720x540); ``tless-factored`` weights start it."""
        spec = UNetSpec.tless_factored(center_channels, width)
        return replace(spec, name="tless-votes", center_votes=True, vote_sigma_px=4.0)

    @staticmethod
    def named(name: str, center_channels: int = 1, width: float = 1.0) -> UNetSpec:
        """A variant by name: ``dimo``, ``dimo-lean``, ``dimo-context``, ``dimo-refine``, ``dimo-centers``, ``dimo-votes``,
        ``tless``, ``tless-lean``, ``tless-factored``, ``tless-refine``, ``tless-votes``."""
        makers = {
            "dimo": lambda: UNetSpec.dimo(width),
            "dimo-lean": lambda: UNetSpec.dimo_lean(width),
            "dimo-context": lambda: UNetSpec.dimo_context(width),
            "dimo-refine": lambda: UNetSpec.dimo_refine(width),
            "dimo-centers": lambda: UNetSpec.dimo_centers(width),
            "dimo-votes": lambda: UNetSpec.dimo_votes(width),
            "tless": lambda: UNetSpec.tless(center_channels, width),
            "tless-lean": lambda: UNetSpec.tless_lean(center_channels, width),
            "tless-factored": lambda: UNetSpec.tless_factored(center_channels, width),
            "tless-refine": lambda: UNetSpec.tless_refine(center_channels, width),
            "tless-votes": lambda: UNetSpec.tless_votes(center_channels, width),
        }
        if name not in makers:
            raise ValueError(f"unknown network variant {name!r}; expected one of {sorted(makers)}")
        spec = makers[name]()
        if spec.center_channels != center_channels:
            spec = replace(spec, center_channels=center_channels)
        return spec

    @property
    def total_stride(self) -> int:
        """Input sizes are padded to a multiple of this."""
        return self.strides[0] * self.strides[1] * self.strides[2]

    def features(self, n: int) -> int:
        """``n`` features scaled by ``width``."""
        return max(4, round(n * self.width))

    def as_dict(self) -> dict:
        d = {**asdict(self), "channels": list(self.channels), "strides": list(self.strides)}
        d["context_dilations"] = list(self.context_dilations)
        return d

    @staticmethod
    def from_dict(d: dict) -> UNetSpec:
        """The spec of :meth:`as_dict`; each field of its type (a string "false" is not False, True is not 1).

        Raises:
            KeyError: a required field is missing.
            TypeError: a field of another type.
            ValueError: a value out of range.
        """
        return UNetSpec(
            channels=tuple(_integer(c, "channels") for c in _sequence(d["channels"], "channels")),
            strides=tuple(_integer(s, "strides") for s in _sequence(d["strides"], "strides")),
            head_channels=_integer(d["head_channels"], "head_channels"),
            center_channels=_integer(d["center_channels"], "center_channels"),
            width=_real(d["width"], "width"),
            name=_text(d["name"], "name"),
            context_dilations=tuple(
                _integer(x, "context_dilations") for x in _sequence(d.get("context_dilations", ()), "context_dilations")
            ),
            factored_centers=_flag(d.get("factored_centers", False), "factored_centers"),
            refine_channels=_integer(d.get("refine_channels", 0), "refine_channels"),
            center_branch_channels=_integer(d.get("center_branch_channels", 0), "center_branch_channels"),
            center_votes=_flag(d.get("center_votes", False), "center_votes"),
            vote_sigma_px=_real(d.get("vote_sigma_px", 3.0), "vote_sigma_px"),
            vote_mix=_text(d.get("vote_mix", "max"), "vote_mix"),
        )


def _flag(value: object, field: str) -> bool:
    if not isinstance(value, bool):
        raise TypeError(f"{field} must be true or false, got {value!r}")
    return value


def _integer(value: object, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{field} must be an integer, got {value!r}")
    return value


def _real(value: object, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{field} must be a number, got {value!r}")
    return float(value)


def _text(value: object, field: str) -> str:
    if not isinstance(value, str):
        raise TypeError(f"{field} must be a string, got {value!r}")
    return value


def _sequence(value: object, field: str) -> list | tuple:
    if not isinstance(value, list | tuple):
        raise TypeError(f"{field} must be a list, got {value!r}")
    return value


class _Block(nn.Module):
    """Two (3x3 conv, BatchNorm, ReLU); the first may downsample by ``stride`` (its kernel covers the stride)."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1) -> None:
        super().__init__()
        k = max(3, stride)
        self.body = nn.Sequential(
            nn.Conv2d(c_in, c_out, k, stride=stride, padding=(k - stride + 1) // 2, bias=False),  # size / stride
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_out, c_out, 3, padding=1, bias=False),
            nn.BatchNorm2d(c_out),
            nn.ReLU(inplace=True),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)


class _Context(nn.Module):
    """Residual dilated convolutions: ``x <- ReLU(x + BN(conv3x3_d(x)))`` for each dilation ``d`` in turn (same size;
    ``x`` is a ReLU output, so a zero residual leaves it unchanged)."""

    def __init__(self, c: int, dilations: tuple[int, ...]) -> None:
        super().__init__()
        self.layers = nn.ModuleList(
            nn.Sequential(nn.Conv2d(c, c, 3, padding=d, dilation=d, bias=False), nn.BatchNorm2d(c)) for d in dilations
        )
        # Each residual starts at zero (BatchNorm scale 0, Goyal et al. 2017): a new network trains as a plain
        # deeper one would, and one started from weights without context computes exactly what they did.
        for layer in self.layers:
            nn.init.zeros_(layer[1].weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.layers:
            x = F.relu(x + layer(x))
        return x


class _Refine(nn.Module):
    """Full-resolution correction of an upsampled logit: ``logit + out(fuse([stem(image), up(reduce(feat)), logit]))``.

    ``stem``: 3x3 conv of the image (BatchNorm, ReLU) to ``c`` features at full resolution; ``reduce``: 1x1 conv
    of the head's last features (below full resolution) to ``c - 1``, upsampled bilinearly; ``fuse``: one 3x3 conv
    of the ``2c`` joined features to ``c`` (BatchNorm, ReLU): with the stem, each output pixel sees 5x5 pixels of
    the image, enough to put an edge on its pixel; ``out``: a weighted sum of the ``c`` features plus a bias, zero at
    the start, so a network started from weights without refinement computes exactly what they did and learns only
    the correction. (``2c`` inputs and the weighted sum instead of a 1x1 convolution to one channel: both are
    several times faster on CPU, where full-resolution convolutions of few channels are memory-bound.)
    """

    def __init__(self, c_feat: int, c: int) -> None:
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, c, 3, padding=1, bias=False), nn.BatchNorm2d(c), nn.ReLU(inplace=True))
        self.reduce = nn.Conv2d(c_feat, c - 1, 1)
        self.fuse = nn.Sequential(
            nn.Conv2d(2 * c, c, 3, padding=1, bias=False), nn.BatchNorm2d(c), nn.ReLU(inplace=True)
        )
        self.out_weight = nn.Parameter(torch.zeros(c))
        self.out_bias = nn.Parameter(torch.zeros(()))

    def forward(self, image: torch.Tensor, features: torch.Tensor, logit: torch.Tensor) -> torch.Tensor:
        """``image (B, 3, H, W)``, head ``features (B, c_feat, h, w)`` and upsampled ``logit (B, 1, H, W)`` ->
        refined logit ``(B, 1, H, W)``."""
        up = _resize(self.reduce(features), image.shape[-2:])
        fused = self.fuse(torch.cat([self.stem(image), up, logit], dim=1))
        return logit + (fused * self.out_weight.view(1, -1, 1, 1)).sum(dim=1, keepdim=True) + self.out_bias


class _CenterBranch(nn.Module):
    """Centre-only features at the bottleneck's resolution: ``out(context(block([f3, avgpool(u2)])))``, upsampled and
    added to the center head's input.

    ``f3 (B, c3, h, w)``: the bottleneck's features after the shared context; ``u2 (B, c3, 2h, 2w)``: the decoder's
    quarter-resolution features (they hold the encoder's finer level too), average-pooled to ``(h, w)``. ``block``:
    two 3x3 convolutions to ``c`` features; ``context``: residual dilated 3x3 convolutions of dilations 1, 2, 4, 8
    (with the block, each output cell joins the cells up to 17 away: 136 px of a view at a total stride of 8);
    ``out``: a 1x1 convolution to the head's input features, zero at the start, so a network started from weights
    without the branch computes exactly what they did. At 1/8 resolution the branch is cheap (0.17 GMAC per 320x256
    view with 48 features: ``dimo-centers`` 1.24 against ``dimo-context``'s 1.07).
    """

    def __init__(self, c_in: int, c: int, c_out: int) -> None:
        super().__init__()
        self.block = _Block(2 * c_in, c)
        self.context = _Context(c, (1, 2, 4, 8))
        self.out = nn.Conv2d(c, c_out, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, f3: torch.Tensor, u2: torch.Tensor, size) -> torch.Tensor:
        """``f3 (B, c_in, h, w)``, ``u2 (B, c_in, h', w')`` -> ``(B, c_out, *size)`` to add to the head's input."""
        pooled = F.adaptive_avg_pool2d(u2, f3.shape[-2:])
        return _resize(self.out(self.context(self.block(torch.cat([f3, pooled], dim=1)))), size)


class _Head(nn.Module):
    """Two (3x3 conv, BatchNorm, ReLU) of ``c_mid`` features, then a 1x1 convolution to ``c_out`` logits."""

    def __init__(self, c_in: int, c_mid: int, c_out: int) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(c_in, c_mid, 3, padding=1, bias=False),
            nn.BatchNorm2d(c_mid),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_mid, c_mid, 3, padding=1, bias=False),
            nn.BatchNorm2d(c_mid),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_mid, c_out, 1),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)

    def features_and_logits(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The features before the 1x1 output convolution ``(B, c_mid, h, w)`` and the logits ``(B, c_out, h, w)``."""
        features = self.body[:-1](x)
        return features, self.body[-1](features)


class UNet(nn.Module):
    """``forward(image (B, 3, H, W)) -> (center logits (B, C, H, W), curvature logits (B, H, W))``.

    Any ``H, W``: padded to a multiple of :attr:`UNetSpec.total_stride`, outputs cropped back.
    """

    def __init__(self, spec: UNetSpec) -> None:
        super().__init__()
        self.spec = spec
        c1, c2, c3 = (spec.features(c) for c in spec.channels)
        s1, s2, s3 = spec.strides
        h = spec.features(spec.head_channels)
        self.e1 = _Block(3, c1, s1)
        self.e2 = _Block(c1, c2, s2)
        self.e3 = _Block(c2, c3, s3)
        self.bottleneck = _Block(c3, c3)
        self.context = _Context(c3, spec.context_dilations) if spec.context_dilations else None
        self.d2 = _Block(c3 + c2, c3)
        self.d1 = _Block(c3 + c1, c3)
        self.center_head = _Head(c3, h, spec.center_channels + int(spec.factored_centers))
        self.curvature_head = _Head(c3, h, 1)
        self.refine = _Refine(h, max(2, spec.features(spec.refine_channels))) if spec.refine_channels else None
        branch = spec.features(spec.center_branch_channels) if spec.center_branch_channels else 0
        self.center_branch = _CenterBranch(c3, branch, c3) if branch else None
        self.vote_head = _Head(c3, h, VOTE_CHANNELS) if spec.center_votes else None
        # Logits start near the targets' mean (mostly background) so early losses are not dominated by it.
        for head in (self.center_head, self.curvature_head):
            nn.init.constant_(head.body[-1].bias, -4.0)
        if spec.factored_centers:  # the class logits start uniform
            nn.init.zeros_(self.center_head.body[-1].bias[1:])
        if self.vote_head is not None:  # no pixel votes at first (fg logit -4 everywhere): the head's map alone
            nn.init.zeros_(self.vote_head.body[-1].bias)
            with torch.no_grad():
                self.vote_head.body[-1].weight[:1].zero_()
                self.vote_head.body[-1].bias[:1].fill_(-4.0)

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Center logits ``(B, C, H, W)`` (factored ones combined) and curvature logits ``(B, H, W)``: the heads'
        alone (a vote head's map joins them in :meth:`probabilities`, which the predictor and validation use)."""
        center, curvature = self.forward_raw(image)
        if self.spec.factored_centers:
            center = factored_center_logits(center)
        return center, curvature

    def probabilities(
        self, image: torch.Tensor, class_mask: torch.Tensor | None = None, compact: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``sigmoid`` of :meth:`forward`'s logits, float32: center ``(B, C, H, W)`` and curvature ``(B, H, W)``.

        A factored head's probabilities are computed directly (:func:`center_probabilities`), not through the
        combined logits' log space at full resolution (the same values to float rounding; ``tless-factored`` 94
        against 209 ms per 720x540 view on 2 CPU cores, ``python scripts/bench_net.py --variants tless-factored``). ``class_mask`` ``(C,)`` or ``(B, C)`` bool:
        a factored head's softmax over the True classes only (the others 0); ignored by independent channels.
        ``compact``: only the True classes' channels are returned (:func:`center_probabilities`)."""
        return self.probabilities_of(*self.forward_outputs(image), class_mask, compact)

    def probabilities_of(
        self,
        center: torch.Tensor,
        curvature: torch.Tensor,
        votes: torch.Tensor | None,
        class_mask: torch.Tensor | None = None,
        compact: bool = False,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`probabilities` from :meth:`forward_outputs`' three outputs (validation has them already)."""
        objectness = None
        if votes is not None:
            voted = vote_map(votes, self.spec.vote_sigma_px)  # (B, 1, H, W)
            if self.spec.vote_mix == "votes":
                objectness = voted
            else:
                head = center[:, :1] if self.spec.factored_centers else center
                objectness = torch.maximum(torch.sigmoid(head.float()), voted)
        probabilities = center_probabilities(center, self.spec.factored_centers, class_mask, objectness, compact)
        return probabilities, torch.sigmoid(curvature.float())

    def forward_raw(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """What the heads output: center ``(B, C, H, W)``, or ``(B, 1 + C, H, W)`` (class-agnostic center logit, then
        class logits) for factored centers, and curvature logits ``(B, H, W)``; training's losses use these."""
        center, curvature, _ = self.forward_outputs(image)
        return center, curvature

    def forward_outputs(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """:meth:`forward_raw`'s outputs and the vote head's ``(B, 4, H, W)`` (None without one,
        :mod:`bop_cender.net.votes`)."""
        if image.dim() != 4 or image.shape[1] != 3:
            raise ValueError(f"image must be (B, 3, H, W), got {tuple(image.shape)}")
        H, W = image.shape[-2:]
        stride = self.spec.total_stride
        pad_h, pad_w = (-H) % stride, (-W) % stride
        x = F.pad(image, (0, pad_w, 0, pad_h), mode="replicate") if pad_h or pad_w else image
        f1 = self.e1(x)
        f2 = self.e2(f1)
        f3 = self.bottleneck(self.e3(f2))
        if self.context is not None:
            f3 = self.context(f3)
        u2 = self.d2(torch.cat([_resize(f3, f2.shape[-2:]), f2], dim=1))
        u1 = self.d1(torch.cat([_resize(u2, f1.shape[-2:]), f1], dim=1))
        if self.center_branch is not None:
            center = self.center_head(u1 + self.center_branch(f3, u2, u1.shape[-2:]))
        else:
            center = self.center_head(u1)
        curvature_features, curvature = self.curvature_head.features_and_logits(u1)
        votes = self.vote_head(u1) if self.vote_head is not None else None
        if center.shape[-2:] != x.shape[-2:]:  # a first stride above 1: logits up to the padded input size
            center = _resize(center, x.shape[-2:])
            curvature = _resize(curvature, x.shape[-2:])
            votes = _resize(votes, x.shape[-2:]) if votes is not None else None
        if self.refine is not None:
            curvature = self.refine(x, curvature_features, curvature)
        return center[..., :H, :W], curvature[:, 0, :H, :W], votes[..., :H, :W] if votes is not None else None


def factored_center_logits(raw: torch.Tensor) -> torch.Tensor:
    """Per-channel center logits ``(B, C, H, W)`` from a factored head's ``raw (B, 1 + C, H, W)``.

    Channel ``k``'s probability is ``p_k = sigmoid(raw[:, 0]) * softmax(raw[:, 1:])_k``: where an object's centre
    is (shared by all ids, so every object's blobs train it) times which object is there (a per-pixel
    classification, trained on every pixel of every blob). The logit ``log p_k - log(1 - p_k)`` is computed in
    log space, so that ``sigmoid`` of it gives ``p_k`` back without overflow.
    Why (ours, not the paper's): with one independent channel per object id (T-LESS: 30), each channel sees the
    blobs of one object only (about 80 of 768 training images), and on our CPU budget no channel rose above
    stage 2's threshold (``scripts/train_shipped_tless.sh``).
    """
    log_p = F.logsigmoid(raw[:, :1]) + F.log_softmax(raw[:, 1:], dim=1)
    log_p = log_p.clamp(max=-1e-7)  # p < 1: log(1 - p) stays finite
    return log_p - torch.log(-torch.expm1(log_p))


def center_probabilities(
    raw: torch.Tensor,
    factored: bool,
    class_mask: torch.Tensor | None = None,
    objectness: torch.Tensor | None = None,
    compact: bool = False,
) -> torch.Tensor:
    """Center probabilities ``(B, C, H, W)`` from the center head's ``raw`` output (:meth:`UNet.forward_raw`).

    Factored: ``sigmoid(raw[:, 0]) * softmax(raw[:, 1:])``, the softmax over the classes of ``class_mask`` (``(C,)`` or
    ``(B, C)`` bool; None: all) only: the others' logits are set to -inf before it, so a class that is ruled out
    gives its share to the others whatever its logit (renormalising the probabilities afterwards loses them once an
    absent class's logit leads by ~27 and the present ones underflow). A sample whose mask is all False keeps every
    class. Independent channels: ``sigmoid(raw)``, ``class_mask`` ignored.

    ``objectness`` ``(B, 1, H, W)`` in [0, 1] replaces ``sigmoid(raw[:, 0])`` of a factored head, and ``sigmoid(raw)``
    of one shared channel (a vote map joined with the head's, :meth:`UNet.probabilities`).

    ``compact`` (a factored head and a ``(C,)`` ``class_mask`` only): ``(B, K, H, W)``, the channels of the K True
    classes alone, in order (all C where none is True). The others are exactly 0 and a scene's maps need not hold
    them: a T-LESS group of 5 views at 720x540 holds 5 of 30 channels, 39 MB instead of 233 MB, before stage 2's
    float64 copy doubles it (``NetPredictor``).
    """
    if compact and (not factored or class_mask is None or class_mask.dim() != 1):
        raise ValueError("compact needs a factored head and a (C,) class_mask")
    if not factored:
        if objectness is not None and raw.shape[1] == 1:
            return objectness.float()
        return torch.sigmoid(raw.float())
    agnostic = torch.sigmoid(raw[:, :1].float()) if objectness is None else objectness.float()
    if class_mask is None:
        return agnostic * torch.softmax(raw[:, 1:].float(), dim=1)
    shape = (raw.shape[0], raw.shape[1] - 1, *raw.shape[2:])
    mask = class_mask.to(device=raw.device, dtype=torch.bool)
    mask = mask.expand(raw.shape[0], -1) if mask.dim() == 1 else mask
    if mask.shape != shape[:2]:
        raise ValueError(f"class_mask must be ({shape[1]},) or ({shape[0]}, {shape[1]})")
    mask = mask | ~mask.any(dim=1, keepdim=True)  # nothing known of a sample: all classes
    # Only the classes some sample keeps are computed (a T-LESS scene's 3-6 of 30: 59-64 -> 30-34 ms per 720x540
    # view on 2 CPU cores, ``python scripts/bench_net.py``); the others are exactly 0, as their -inf logits would give.
    kept = torch.nonzero(mask.any(dim=0)).flatten()
    subset = raw.index_select(1, kept + 1).float()  # from ``raw`` itself (selecting from its channel slice was slow)
    subset = subset.masked_fill(~mask[:, kept, None, None], float("-inf"))
    if compact:
        return agnostic * torch.softmax(subset, dim=1)
    out = torch.zeros(shape, dtype=torch.float32, device=raw.device)
    out[:, kept] = agnostic * torch.softmax(subset, dim=1)
    return out


def _resize(x: torch.Tensor, size) -> torch.Tensor:
    """Bilinear resize to ``size`` (align_corners False: pixel centres at +0.5, the project's convention)."""
    return F.interpolate(x, size=tuple(size), mode="bilinear", align_corners=False)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())

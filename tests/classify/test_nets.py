"""Backbones: upstream state_dict names load strictly; bad files are refused clearly."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from cellctl.classify.nets import (
    EfficientNetLite0,
    ResNet18,
    backbone_parameters,
    build_model,
    head_module,
    lite0_imagenet_path,
    load_imagenet_weights,
)
from cellctl.errors import ClassifierError


def test_resnet18_has_torchvision_keys_and_shapes() -> None:
    """122 entries with torchvision's names and shapes (notes/vision.md §7)."""
    sd = ResNet18(num_classes=1000).state_dict()
    assert len(sd) == 122
    assert sum(p.numel() for p in ResNet18(1000).parameters()) == 11_689_512
    expect = {
        "conv1.weight": (64, 3, 7, 7),
        "layer1.0.conv1.weight": (64, 64, 3, 3),
        "layer2.0.conv1.weight": (128, 64, 3, 3),
        "layer2.0.downsample.0.weight": (128, 64, 1, 1),
        "layer2.0.downsample.1.running_var": (128,),
        "layer4.1.conv2.weight": (512, 512, 3, 3),
        "fc.weight": (1000, 512),
        "fc.bias": (1000,),
    }
    for k, shape in expect.items():
        assert tuple(sd[k].shape) == shape, k
    assert not any(k.startswith("layer1.0.downsample") for k in sd)


def test_resnet18_imagenet_file_loads_strictly_into_two_class_model(tmp_path: Path) -> None:
    """A 1000-class checkpoint file loads (strict) and the backbone is copied, head kept fresh."""
    torch.manual_seed(0)
    src = ResNet18(num_classes=1000)
    path = tmp_path / "resnet18-imagenet.pth"
    torch.save(src.state_dict(), path)
    model = build_model("resnet18", pretrained=path)
    assert torch.equal(model.layer3[1].conv2.weight, src.layer3[1].conv2.weight)
    assert model.fc.out_features == 2


def test_mismatched_or_missing_weights_are_refused(tmp_path: Path) -> None:
    bad = ResNet18(num_classes=1000).state_dict()
    bad.pop("layer4.1.bn2.running_mean")
    path = tmp_path / "bad.pth"
    torch.save(bad, path)
    with pytest.raises(ClassifierError, match="(?s)does not match ResNet18.*layer4.1.bn2.running_mean"):
        load_imagenet_weights(ResNet18(), path)
    with pytest.raises(ClassifierError, match="does not exist"):
        load_imagenet_weights(ResNet18(), tmp_path / "nope.pth")
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(ClassifierError, match="cannot be read"):
        load_imagenet_weights(ResNet18(), tmp_path / "junk.pth")
    with pytest.raises(ClassifierError, match="architecture 'vgg' is unknown"):
        build_model("vgg")


def test_lite0_loads_the_packaged_imagenet_checkpoint_strictly_and_matches_upstream() -> None:
    """Our Lite0 reproduces efficientnet-lite-pytorch's output with the shipped weights."""
    sd = torch.load(lite0_imagenet_path(), map_location="cpu", weights_only=True)
    ours = EfficientNetLite0(num_classes=1000)
    ours.load_state_dict(sd, strict=True)
    ours.eval()
    upstream_mod = pytest.importorskip("efficientnet_lite_pytorch")
    ref = upstream_mod.EfficientNet.from_name("efficientnet-lite0", image_size=128)
    ref.load_state_dict(sd)
    ref.eval()
    x = torch.randn(2, 3, 128, 128, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        assert torch.allclose(ours(x), ref(x), atol=1e-4)


def test_backbone_parameter_selection() -> None:
    m = build_model("lite0", pretrained=False)
    head = set(map(id, head_module(m).parameters()))
    all_bb = backbone_parameters(m, 1.0)
    half = backbone_parameters(m, 0.5)
    assert not head & set(map(id, all_bb))
    assert 0 < len(half) < len(all_bb)
    assert half[-1] is all_bb[-1]
    with pytest.raises(ClassifierError, match="last_fraction 0 must be in"):
        backbone_parameters(m, 0)

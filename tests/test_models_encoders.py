import pytest
import torch

from collavn.errors import CheckpointError
from collavn.models.encoders import (
    ResNet18Trunk,
    SmallCNNEncoder,
    load_imagenet_weights,
    make_encoder,
    normalise_rgb,
)

torch.set_num_threads(1)


@pytest.mark.parametrize("kind", ["small", "resnet18"])
@pytest.mark.parametrize("shape", [(3, 32, 128), (3, 32, 32), (4, 64, 256)])
def test_encoder_output_shape(kind, shape):
    torch.manual_seed(0)
    enc = make_encoder(kind, shape, 48)
    images = torch.randint(0, 256, (2, *shape), dtype=torch.uint8)
    out = enc(images)
    assert out.shape == (2, 48)
    assert enc.output_size == 48
    assert torch.isfinite(out).all()


def test_small_cnn_keeps_azimuth_cells():
    enc = SmallCNNEncoder(3, 16, (32, 128))
    assert enc.head[1].in_features == 128 * 2 * 8


def test_normalise_rgb_passes_extra_channels():
    x = torch.zeros(1, 4, 2, 2)
    x[:, 3] = 0.7
    y = normalise_rgb(x)
    assert torch.allclose(y[:, 3], torch.full((1, 2, 2), 0.7))
    assert torch.allclose(y[0, 0, 0, 0], torch.tensor(-0.485 / 0.229))


def test_load_torchvision_state_dict(tmp_path):
    torch.manual_seed(1)
    source = ResNet18Trunk()
    state = dict(source.state_dict())
    state["fc.weight"] = torch.zeros(1000, 512)
    state["fc.bias"] = torch.zeros(1000)
    path = tmp_path / "resnet18.pth"
    torch.save(state, path)
    target = make_encoder("resnet18", (3, 32, 32), 8, weights_path=path)
    for name, tensor in source.state_dict().items():
        assert torch.equal(target.trunk.state_dict()[name], tensor), name


def test_load_weights_into_rgbd_trunk_copies_rgb(tmp_path):
    source = ResNet18Trunk()
    path = tmp_path / "w.pth"
    torch.save(source.state_dict(), path)
    target = ResNet18Trunk(in_channels=4)
    load_imagenet_weights(target, path)
    assert torch.equal(target.conv1.weight[:, :3], source.conv1.weight)


def test_bad_weights_file_raises(tmp_path):
    with pytest.raises(CheckpointError):
        load_imagenet_weights(ResNet18Trunk(), tmp_path / "missing.pth")
    path = tmp_path / "other.pth"
    torch.save({"conv1.weight": torch.zeros(3)}, path)
    with pytest.raises(CheckpointError):
        load_imagenet_weights(ResNet18Trunk(), path)


def test_small_encoder_rejects_weights():
    with pytest.raises(ValueError, match="resnet18"):
        make_encoder("small", (3, 32, 32), 8, weights_path="x.pth")

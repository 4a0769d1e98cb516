"""The generator's delta mode (GeneratorConfig.delta): pose inputs relative to the keys."""

import pytest

torch = pytest.importorskip("torch")

from pipeline.infer.features import n_input_channels  # noqa: E402
from pipeline.networks.generator import Generator, GeneratorConfig, relative_to_keys  # noqa: E402

J = 21
C = J * 6 + 3


def _net(delta: bool) -> Generator:
    torch.manual_seed(0)
    net = Generator(GeneratorConfig(width=32, levels=(32, 32), bottleneck_dilations=(1,), delta=delta))
    torch.nn.init.normal_(net.out.weight, std=0.1)  # not the zero start: outputs must depend on inputs
    return net.eval()


def test_a_constant_pose_offset_does_not_reach_the_network():
    x = torch.randn(2, n_input_channels(J), 64)
    shift = torch.zeros_like(x)
    shift[:, : 2 * C] = torch.randn(2, C, 1).repeat(1, 2, 64)  # the same offset on baseline and key copy
    with torch.no_grad():
        delta, plain = _net(True), _net(False)
        assert torch.allclose(delta(x), delta(x + shift), atol=1e-5)
        assert not torch.allclose(plain(x), plain(x + shift), atol=1e-3)  # the absolute model sees it
        # Timing and latent channels still do.
        other = x.clone()
        other[:, 2 * C :] += 1.0
        assert not torch.allclose(delta(x), delta(other), atol=1e-3)


def test_relative_channels_are_change_since_the_first_key_and_key_minus_baseline():
    x = torch.randn(1, n_input_channels(J), 8)
    r = relative_to_keys(x, J)
    assert torch.equal(r[:, :C, 0], torch.zeros(1, C))
    assert torch.allclose(r[:, :C], x[:, :C] - x[:, :C, :1])
    assert torch.allclose(r[:, C : 2 * C], x[:, C : 2 * C] - x[:, :C])
    assert torch.equal(r[:, 2 * C :], x[:, 2 * C :])


def test_an_absolute_checkpoint_continues_in_delta_mode_next_to_itself():
    from pipeline.train.generator_training import to_delta_inputs

    plain = _net(False)
    delta = _net(True)
    delta.load_state_dict(to_delta_inputs(plain.state_dict(), J))
    x = torch.randn(2, n_input_channels(J), 64)
    # With the first key's pose at zero (what delta mode withholds) the two agree but for
    # the window edges, where the input convolution pads.
    x[:, :C] -= x[:, :C, :1]
    with torch.no_grad():
        a, b = plain.inp(x), delta.inp(relative_to_keys(x, J))
    assert torch.allclose(a[..., 1:-1], b[..., 1:-1], atol=1e-5)

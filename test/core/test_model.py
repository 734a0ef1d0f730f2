"""The networks: unit-length output, a permutation-invariant encoder, and a fused eval path equal to the plain math."""

import torch

from triplet_normal_ros.core.learned.model import PatchEncoder, PointMLP, TripletNormalNet


def _randomise_batchnorm(module: torch.nn.Module, seed: int) -> None:
    """Non-trivial running statistics and affine parameters, so folding BatchNorm into Linear is really exercised."""
    gen = torch.Generator().manual_seed(seed)
    for norm in (m for m in module.modules() if isinstance(m, torch.nn.BatchNorm1d)):
        n = norm.num_features
        with torch.no_grad():
            norm.running_mean.copy_(torch.randn(n, generator=gen))
            norm.running_var.copy_(torch.rand(n, generator=gen) * 2.0 + 0.1)
            norm.weight.copy_(torch.randn(n, generator=gen))
            norm.bias.copy_(torch.randn(n, generator=gen))


def _net(seed: int = 0) -> TripletNormalNet:
    torch.manual_seed(seed)
    net = TripletNormalNet((16, 32), (16,))
    _randomise_batchnorm(net, seed)
    return net


def test_output_is_unit_length_in_both_modes() -> None:
    net = _net()
    patches = torch.randn(40, 20, 3)
    for train in (True, False):
        out = net.train(train)(patches)
        assert out.shape == (40, 3)
        torch.testing.assert_close(torch.linalg.vector_norm(out, dim=-1), torch.ones(40))


def test_encoder_is_invariant_to_the_order_of_the_patch_points() -> None:
    net = _net(1).eval()
    patches = torch.randn(8, 30, 3)
    shuffled = patches[:, torch.randperm(30, generator=torch.Generator().manual_seed(2))]
    torch.testing.assert_close(net.encoder(shuffled), net.encoder(patches))
    torch.testing.assert_close(net(shuffled), net(patches))
    # Different points must give a different latent, or the test above proves nothing.
    assert not torch.allclose(net.encoder(patches + 0.5), net.encoder(patches))


def test_fused_eval_path_equals_the_unfused_math_on_the_same_batchnorm_statistics() -> None:
    mlp = PointMLP((16, 32, 64))
    _randomise_batchnorm(mlp, 3)
    mlp.eval()
    # 600 patches of 16 points spans several inference blocks (4096 rows each), including a ragged last one.
    x = torch.randn(600, 16, 3)
    with torch.no_grad():
        fused = mlp(x)
        plain = mlp._forward_train(x)  # in eval mode BatchNorm uses the running statistics
    torch.testing.assert_close(fused, plain, atol=1e-5, rtol=1e-5)
    assert bool((fused >= 0).all()) and fused.abs().sum() > 0


def test_encoder_latent_width_and_config_round_trip() -> None:
    assert PatchEncoder((8, 24)).latent_dim == 24
    net = _net(4).eval()
    clone = TripletNormalNet.from_config(net.config)
    clone.load_state_dict(net.state_dict())
    clone.eval()
    x = torch.randn(5, 12, 3)
    torch.testing.assert_close(clone(x), net(x))
    assert net.config == {"encoder": [16, 32], "regressor": [16], "residual": False, "scales": [], "inlier_seeds": []}


def test_training_mode_reaches_every_parameter() -> None:
    net = _net(5).train()
    net(torch.randn(6, 10, 3)).sum().backward()
    missing = [name for name, p in net.named_parameters() if p.grad is None or not bool(p.grad.abs().sum() > 0)]
    assert not missing


def test_residual_head_starts_as_the_pca_normal_and_round_trips() -> None:
    torch.manual_seed(6)
    net = TripletNormalNet((16, 32), (16,), residual=True).eval()
    out = net(torch.randn(9, 12, 3))
    torch.testing.assert_close(out, torch.tensor([0.0, 0.0, 1.0]).expand(9, 3))  # +z is the PCA normal
    net.train()(torch.randn(6, 10, 3))[:, 0].sum().backward()
    assert net.regressor.mlp[-1].weight.grad.abs().sum() > 0  # ... and it can learn a correction
    clone = TripletNormalNet.from_config(net.config)
    assert clone.regressor.residual and net.config["residual"] is True


def test_configs_written_before_the_residual_head_load_as_direct_regressors() -> None:
    assert not TripletNormalNet.from_config({"encoder": [16, 32], "regressor": [16]}).regressor.residual

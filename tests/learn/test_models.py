import torch

from forcdecode.learn.models import PaperCNN, SmallCNN


def test_paper_network_has_the_stated_architecture():
    net = PaperCNN()
    expected = (1 * 8 * 9 + 8) + (8 * 16 * 9 + 16) + (58_225 * 4096 + 4096) + (4096 * 11 + 11)
    assert sum(p.numel() for p in net.parameters()) == expected  # 238.5 M weights
    net.eval()
    out = net(torch.rand(2, 64, 64), torch.rand(2))
    assert out.shape == (2, 11)


def test_dropout_active_in_training_only_and_gradients_reach_every_weight():
    torch.manual_seed(0)
    net = SmallCNN(width=32)
    x, ms = torch.rand(4, 64, 64), torch.rand(4)
    net.eval()
    assert torch.equal(net(x, ms), net(x, ms))
    net.train()
    assert not torch.equal(net(x, ms), net(x, ms))
    net(x, ms).pow(2).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in net.parameters())


def test_ms_input_changes_the_output():
    torch.manual_seed(1)
    net = SmallCNN(width=16).eval()
    x = torch.rand(1, 64, 64)
    assert not torch.allclose(net(x, torch.tensor([0.1])), net(x, torch.tensor([0.9])))


def _dense_inputs(net, x, ms):
    """The tensors entering dense1 and dense2 and the one leaving conv2's ReLU, in one forward pass."""
    seen = {}
    hooks = [net.dense1.register_forward_pre_hook(lambda m, a: seen.__setitem__("dense1", a[0].detach().clone())),
             net.dense2.register_forward_pre_hook(lambda m, a: seen.__setitem__("dense2", a[0].detach().clone())),
             net.conv2.register_forward_pre_hook(lambda m, a: seen.__setitem__("conv2_in", a[0].detach().clone())),
             net.conv2.register_forward_hook(lambda m, a, out: seen.__setitem__("conv2_out", out.detach().clone()))]
    net(x, ms)
    for hook in hooks:
        hook.remove()
    return seen


def test_paper_dropout_positions_conv2_and_dense1_only_ms_never_dropped():
    """The paper: dropout 0.5 on every layer but the first convolution; its authors' code: after conv2
    and after dense1, the M_s nodes never dropped. Checked on the tensors themselves in training mode."""
    torch.manual_seed(2)
    net = PaperCNN(image_size=16).train()
    # float32 explicitly: importing magnum.np (other tests) switches torch's default dtype to float64
    x, ms = torch.rand(3, 16, 16, dtype=torch.float32), torch.tensor([0.2, 0.5, 0.9], dtype=torch.float32)
    seen = _dense_inputs(net, x, ms)
    # no dropout on the first convolution: conv2 sees exactly relu(conv1(x))
    assert torch.equal(seen["conv2_in"], torch.relu(net.conv1(x.unsqueeze(1))))
    features = seen["dense1"][:, :-625]
    kept = torch.relu(seen["conv2_out"]).flatten(1)
    dropped = (features == 0) & (kept > 0)
    assert 0.35 < dropped.float().mean() / (kept > 0).float().mean() < 0.65  # conv2 features dropped at p = 0.5
    survivors = (features != 0)
    torch.testing.assert_close(features[survivors], 2 * kept[survivors])  # inverted dropout scaling 1/(1 - p)
    # the 625 M_s nodes reach dense1 untouched
    assert torch.equal(seen["dense1"][:, -625:], ms[:, None].expand(-1, 625))
    # dropout after dense1: about half of its positive activations zeroed
    hidden = torch.relu(net.dense1(seen["dense1"]))
    zeroed = (seen["dense2"] == 0) & (hidden > 0)
    assert 0.35 < zeroed.float().sum() / (hidden > 0).float().sum() < 0.65
    assert not any(isinstance(m, torch.nn.Dropout) for name, m in net.named_children() if name == "drop_in")


def test_small_head_drops_at_the_same_positions():
    torch.manual_seed(3)
    net = SmallCNN(width=64, image_size=16).train()
    ms = torch.tensor([0.3, 0.7], dtype=torch.float32)
    seen = _dense_inputs(net, torch.rand(2, 16, 16, dtype=torch.float32), ms)
    assert torch.equal(seen["dense1"][:, -625:], ms[:, None].expand(-1, 625))
    assert (seen["dense2"] == 0).any()

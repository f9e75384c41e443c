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

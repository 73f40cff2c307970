"""Each loss of Algorithm 1 against a value computed by hand on a tiny batch."""
import math

import pytest
import torch

from fbcpr.methods.fb_cpr import losses
from fbcpr.nn.networks import Discriminator

torch.set_num_threads(1)
T = torch.tensor


def test_pessimistic_reduction():
    v = T([[1.0, 5.0], [3.0, 2.0]])
    torch.testing.assert_close(losses.pessimistic(v, 0.0), T([2.0, 3.5]))       # mean
    torch.testing.assert_close(losses.pessimistic(v, 0.5), T([1.0, 2.0]))       # min
    torch.testing.assert_close(losses.pessimistic(v, 0.25), T([1.5, 2.75]))     # mean - 0.25 |diff|


def test_fb_loss_by_hand():
    M = T([[[1.0, 2.0], [3.0, 4.0]]])
    target = T([[0.5, 1.0], [1.0, 2.0]])
    discount = T([0.5, 1.0])
    # diff = [[0.75, 1.5], [2, 2]]; off-diagonal: (1.5^2 + 2^2) / (2*2*1) = 1.5625; diagonal mean of M = 2.5
    torch.testing.assert_close(losses.fb_loss(M, target, discount), T(1.5625 - 2.5))
    # two members: the loss is the sum of the members' losses
    torch.testing.assert_close(losses.fb_loss(torch.cat([M, M]), target, discount), T(2 * (1.5625 - 2.5)))


def test_ortho_loss_by_hand():
    B = T([[1.0, 0.0], [1.0, 1.0]])
    # BB^T = [[1, 1], [1, 2]]: off-diagonal (1 + 1) / 4 = 0.5; diagonal mean 1.5
    torch.testing.assert_close(losses.ortho_loss(B), T(-1.0))


def test_implicit_reward_by_hand():
    B = T([[1.0, 0.0], [0.0, 2.0]])
    z = T([[1.0, 1.0], [1.0, 1.0]])
    # Sigma = B^T B / 2 = diag(0.5, 2); B Sigma^-1 = [[2, 0], [0, 1]]
    torch.testing.assert_close(losses.implicit_reward(B, z), T([2.0, 1.0]), rtol=1e-5, atol=1e-5)
    # singular Sigma (n < d) stays finite thanks to the ridge
    assert torch.isfinite(losses.implicit_reward(torch.randn(3, 8), torch.randn(3, 8))).all()


def test_td_loss_by_hand():
    values = T([[1.0, 2.0], [3.0, 4.0]])
    # targets r + discount * next = [0.5 + 0.5*1, 1 + 0*2] = [1, 1]
    out = losses.td_loss(values, T([0.5, 1.0]), T([1.0, 2.0]), T([0.5, 0.0]))
    torch.testing.assert_close(out, T((0 + 1) / 2 + (4 + 9) / 2))


def test_discriminator_loss_by_hand():
    out = losses.discriminator_loss(T([0.0, math.log(3.0)]), T([0.0]))
    # expert: -log(0.5), -log(0.75) averaged; online: -log(1 - 0.5)
    torch.testing.assert_close(out, T((math.log(2) - math.log(0.75)) / 2 + math.log(2)))


def test_actor_loss_by_hand():
    Fz = T([[1.0, 3.0], [2.0, 1.0]])
    Q = T([[1.0, 0.0], [3.0, 2.0]])
    # min over members: fz = [1, 1], q = [1, 0], |fz| mean = 1 -> -mean([1 + 0.1, 1 + 0])
    torch.testing.assert_close(losses.actor_loss(Fz, Q, alpha=0.1, coef=0.5), T(-1.05))
    # the scale is a stop-gradient: d loss / d Q only through alpha * scale
    Fz.requires_grad_(True)
    Q.requires_grad_(True)
    losses.actor_loss(Fz, Q, alpha=0.1, coef=0.0).backward()
    torch.testing.assert_close(Fz.grad, torch.full((2, 2), -0.25))


def test_action_penalty_adds_scaled_mean_square_and_pulls_actions_to_zero():
    Fz = T([[1.0, 3.0], [2.0, 1.0]])
    Q = T([[1.0, 0.0], [3.0, 2.0]])
    action = T([[0.5, -1.0], [0.0, 1.0]]).requires_grad_(True)
    # mean |fz| = 1 and mean(a^2) = 2.25 / 4, so coef 2 adds 1.125 to the -1.05 of the test above
    loss = losses.actor_loss(Fz, Q, alpha=0.1, coef=0.5, action=action, action_coef=2.0)
    torch.testing.assert_close(loss, T(-1.05 + 1.125))
    loss.backward()
    torch.testing.assert_close(action.grad, 2.0 * 2.0 * action.detach() / 4)   # toward 0, proportional to a
    assert losses.actor_loss(Fz, Q, 0.1, 0.5, action=action, action_coef=0.0).item() == pytest.approx(-1.05)


def test_gradient_penalty_matches_finite_differences():
    torch.manual_seed(0)
    disc = Discriminator(obs_dim=3, z_dim=2, hidden=8, hidden_layers=2).double()
    se, ze, so, zo = (torch.randn(4, k, dtype=torch.float64) for k in (3, 2, 3, 2))
    mix = torch.rand(4, dtype=torch.float64)
    gp = losses.gradient_penalty(disc, se, ze, so, zo, mix)
    x = torch.cat([mix[:, None] * se + (1 - mix[:, None]) * so, mix[:, None] * ze + (1 - mix[:, None]) * zo], 1)
    eps, norms = 1e-6, []
    for i in range(4):
        g = []
        for j in range(5):
            e = torch.zeros(5, dtype=torch.float64)
            e[j] = eps
            f = lambda v: disc.logits(v[None, :3], v[None, 3:])[0]
            g.append((f(x[i] + e) - f(x[i] - e)) / (2 * eps))
        norms.append(torch.stack(g).norm())
    expected = ((torch.stack(norms) - 1) ** 2).mean()
    torch.testing.assert_close(gp.detach(), expected, rtol=1e-5, atol=1e-8)
    gp.backward()  # differentiable w.r.t. the discriminator (double backward)
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for n, p in disc.named_parameters() if n.endswith("weight"))


def test_orthonormality_loss_drives_covariance_to_identity():
    from fbcpr.nn.networks import BackwardNet

    torch.manual_seed(0)
    net = BackwardNet(obs_dim=10, z_dim=4, hidden=32, hidden_layers=1)
    data = torch.randn(512, 10)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)

    def gap():
        b = net(data)
        return torch.linalg.matrix_norm(b.T @ b / len(b) - torch.eye(4)).item()

    before = gap()
    for _ in range(300):
        opt.zero_grad()
        losses.ortho_loss(net(data)).backward()
        opt.step()
    after = gap()
    assert after < 0.25 * before and after < 0.5, (before, after)

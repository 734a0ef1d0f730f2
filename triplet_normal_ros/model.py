"""The paper's networks: a PointNet encoder (shared per-point MLP, max-pool to a latent) and an MLP regressor.

No T-Net: the PCA alignment already removes the rotation a T-Net would learn, leaving only the axis-sign ambiguity,
which training sees in every batch; dropping it saves compute and parameters (docs/MODEL.md).
"""

import itertools

import torch
from torch import nn

DEFAULT_ENCODER = (64, 64, 128, 1024)
DEFAULT_REGRESSOR = (512, 256)
#: Inference runs the per-point MLP on blocks of about this many rows, so activations stay in cache.
_BLOCK_ROWS = 4096


class PointMLP(nn.Module):
    """Shared per-point Linear + BatchNorm + ReLU layers on (B, k, C) as one big matmul per layer."""

    def __init__(self, widths: tuple[int, ...], in_dim: int = 3) -> None:
        super().__init__()
        dims = (in_dim, *widths)
        self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(dims))
        self.norms = nn.ModuleList(nn.BatchNorm1d(b) for b in widths)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training:
            return self._forward_train(x)
        return self._forward_fused(x)

    def _forward_train(self, x: torch.Tensor) -> torch.Tensor:
        batch, k, _ = x.shape
        h = x.reshape(batch * k, -1)
        last = len(self.linears) - 1
        for i, (linear, norm) in enumerate(zip(self.linears, self.norms, strict=True)):
            h = norm(linear(h))
            if i < last:
                h = torch.relu(h)
        # relu and max commute, so pool first and activate the (B, C) result instead of the (B*k, C) one.
        # max(dim) rather than amax: its backward is a scatter by index, amax's compares every element (3x slower).
        return torch.relu(h.reshape(batch, k, -1).max(dim=1).values)

    def _folded(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Eval-mode BatchNorm is affine, so fold it into each Linear: one addmm per layer instead of three passes."""
        layers = []
        for linear, norm in zip(self.linears, self.norms, strict=True):
            scale = norm.weight / torch.sqrt(norm.running_var + norm.eps)
            weight = (linear.weight * scale.unsqueeze(1)).t().contiguous()
            layers.append((weight, (linear.bias - norm.running_mean) * scale + norm.bias))
        return layers

    def _forward_fused(self, x: torch.Tensor) -> torch.Tensor:
        batch, k, _ = x.shape
        layers = self._folded()
        step = max(1, _BLOCK_ROWS // k)
        pooled = []
        for lo in range(0, batch, step):
            h = x[lo : lo + step].reshape(-1, x.shape[-1])
            for weight, bias in layers[:-1]:
                h = torch.relu(torch.addmm(bias, h, weight))
            weight, bias = layers[-1]
            pooled.append(torch.addmm(bias, h, weight).reshape(-1, k, weight.shape[1]).amax(dim=1))
        return torch.relu(torch.cat(pooled))


class PatchEncoder(nn.Module):
    """f(P): (B, k, 3) aligned patch -> (B, latent) permutation-invariant feature."""

    def __init__(self, widths: tuple[int, ...] = DEFAULT_ENCODER) -> None:
        super().__init__()
        self.latent_dim = widths[-1]
        self.mlp = PointMLP(tuple(widths))

    def forward(self, patches: torch.Tensor) -> torch.Tensor:
        return self.mlp(patches)


class NormalRegressor(nn.Module):
    """Latent -> unit normal in the patch frame."""

    def __init__(self, latent_dim: int = 1024, widths: tuple[int, ...] = DEFAULT_REGRESSOR) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        dims = (latent_dim, *widths)
        for a, b in itertools.pairwise(dims):
            layers += [nn.Linear(a, b), nn.BatchNorm1d(b), nn.ReLU()]
        layers.append(nn.Linear(dims[-1], 3))
        self.mlp = nn.Sequential(*layers)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return nn.functional.normalize(self.mlp(latent), dim=-1)


class TripletNormalNet(nn.Module):
    """Encoder + regressor; `config` is what a checkpoint stores to rebuild it."""

    def __init__(self, encoder: tuple[int, ...] = DEFAULT_ENCODER, regressor: tuple[int, ...] = DEFAULT_REGRESSOR):
        super().__init__()
        self.config = {"encoder": list(encoder), "regressor": list(regressor)}
        self.encoder = PatchEncoder(tuple(encoder))
        self.regressor = NormalRegressor(encoder[-1], tuple(regressor))

    @classmethod
    def from_config(cls, config: dict) -> "TripletNormalNet":
        return cls(tuple(int(w) for w in config["encoder"]), tuple(int(w) for w in config["regressor"]))

    def forward(self, patches: torch.Tensor) -> torch.Tensor:
        return self.regressor(self.encoder(patches))

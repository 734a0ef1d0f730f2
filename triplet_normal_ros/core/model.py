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
    """Latent -> unit normal in the patch frame.

    With `residual`, the MLP predicts a correction to the PCA normal, which is +z in the patch frame: the output is
    normalize(e_z + mlp(latent)) and the last layer starts at zero, so an untrained head is exactly PCA and training
    only moves away from it where the data pays for it (docs/MODEL.md).
    """

    def __init__(
        self, latent_dim: int = 1024, widths: tuple[int, ...] = DEFAULT_REGRESSOR, residual: bool = False
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        dims = (latent_dim, *widths)
        for a, b in itertools.pairwise(dims):
            layers += [nn.Linear(a, b), nn.BatchNorm1d(b), nn.ReLU()]
        layers.append(nn.Linear(dims[-1], 3))
        self.mlp = nn.Sequential(*layers)
        self.residual = residual
        if residual:
            nn.init.zeros_(layers[-1].weight)
            nn.init.zeros_(layers[-1].bias)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        out = self.mlp(latent)
        if self.residual:
            out = out + out.new_tensor((0.0, 0.0, 1.0))
        return nn.functional.normalize(out, dim=-1)


class TripletNormalNet(nn.Module):
    """Encoder + regressor; `config` is what a checkpoint stores to rebuild it."""

    def __init__(
        self,
        encoder: tuple[int, ...] = DEFAULT_ENCODER,
        regressor: tuple[int, ...] = DEFAULT_REGRESSOR,
        residual: bool = False,
    ):
        super().__init__()
        self.config = {"encoder": list(encoder), "regressor": list(regressor), "residual": residual}
        self.encoder = PatchEncoder(tuple(encoder))
        self.regressor = NormalRegressor(encoder[-1], tuple(regressor), residual)

    @classmethod
    def from_config(cls, config: dict) -> "TripletNormalNet":
        """`residual` is absent from checkpoints written before it existed: those regress the normal directly."""
        return cls(
            tuple(int(w) for w in config["encoder"]),
            tuple(int(w) for w in config["regressor"]),
            bool(config.get("residual", False)),
        )

    def forward(self, patches: torch.Tensor) -> torch.Tensor:
        return self.regressor(self.encoder(patches))

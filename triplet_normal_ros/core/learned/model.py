"""The paper's networks: a PointNet encoder (shared per-point MLP, max-pool to a latent) and an MLP regressor.

No T-Net: the PCA alignment already removes the rotation a T-Net would learn, leaving only the axis-sign ambiguity,
which training sees in every batch; dropping it saves compute and parameters (docs/MODEL.md).
"""

import itertools

import torch
from torch import nn

from .scales import CUES_PER_SCALE, ScaleFits, candidate_count, check_scales

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


def regressor_dims(latent_dim: int, widths: tuple[int, ...] | list[int], candidates: int) -> tuple[int, ...]:
    """The regressor's layer widths, input to output: the latent plus each candidate's cues in, the correction and a
    weight per candidate out. The MFLOP arithmetic of `bench` counts the same layers."""
    return (latent_dim + candidates * CUES_PER_SCALE, *widths, 3 + candidates)


class NormalRegressor(nn.Module):
    """Latent -> unit normal in the patch frame.

    With `residual`, the MLP predicts a correction to the PCA normal, which is +z in the patch frame: the output is
    normalize(e_z + mlp(latent)) and the last layer starts at zero, so an untrained head is exactly PCA and training
    only moves away from it where the data pays for it (docs/MODEL.md).

    With `candidates` > 0 (the scale head), the MLP also reads the plane fits' cues and outputs a softmax weight per
    candidate normal besides the correction: normalize(sum_s w_s n_s + mlp(...)), so choosing an exact small-scale
    fit near an edge, or the whole pool on a noisy smooth patch, is a matter of weights (`scales.py`). Its last
    layer also starts at zero: an untrained scale head averages the candidates.
    """

    def __init__(
        self,
        latent_dim: int = 1024,
        widths: tuple[int, ...] = DEFAULT_REGRESSOR,
        residual: bool = False,
        candidates: int = 0,
    ) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        dims = regressor_dims(latent_dim, widths, candidates)
        for a, b in itertools.pairwise(dims[:-1]):
            layers += [nn.Linear(a, b), nn.BatchNorm1d(b), nn.ReLU()]
        layers.append(nn.Linear(dims[-2], dims[-1]))
        self.mlp = nn.Sequential(*layers)
        self.residual = residual or candidates > 0
        self.candidates = candidates
        if self.residual:
            nn.init.zeros_(layers[-1].weight)
            nn.init.zeros_(layers[-1].bias)

    def forward(self, latent: torch.Tensor, fits: ScaleFits | None = None) -> torch.Tensor:
        if self.candidates:
            if fits is None:
                raise ValueError("a scale head needs the patches' plane fits (build_patches(..., scales=...))")
            out = self.mlp(torch.cat((latent, fits.cues), dim=1))
            weights = torch.softmax(out[:, 3:], dim=1)
            return nn.functional.normalize(out[:, :3] + torch.einsum("bs,bsi->bi", weights, fits.normals), dim=-1)
        out = self.mlp(latent)
        if self.residual:
            out = out + out.new_tensor((0.0, 0.0, 1.0))
        return nn.functional.normalize(out, dim=-1)


class TripletNormalNet(nn.Module):
    """Encoder + regressor; `config` is what a checkpoint stores to rebuild it. Non-empty `scales` (nearest-m counts)
    makes the regressor a scale head over plane fits at those scales plus the whole pool."""

    def __init__(
        self,
        encoder: tuple[int, ...] = DEFAULT_ENCODER,
        regressor: tuple[int, ...] = DEFAULT_REGRESSOR,
        residual: bool = False,
        scales: tuple[int, ...] = (),
        inlier_seeds: tuple[int, ...] = (),
    ):
        super().__init__()
        scales, inlier_seeds = check_scales(scales), check_scales(inlier_seeds)
        if inlier_seeds and not scales:
            raise ValueError("inlier_seeds need a scale head (non-empty scales)")
        self.config = {
            "encoder": list(encoder),
            "regressor": list(regressor),
            "residual": residual,
            "scales": list(scales),
            "inlier_seeds": list(inlier_seeds),
        }
        self.scales, self.inlier_seeds = scales, inlier_seeds
        self.encoder = PatchEncoder(tuple(encoder))
        candidates = candidate_count(scales, inlier_seeds)
        self.regressor = NormalRegressor(encoder[-1], tuple(regressor), residual, candidates)

    @classmethod
    def from_config(cls, config: dict) -> "TripletNormalNet":
        """`residual`, `scales` and `inlier_seeds` are absent from checkpoints written before they existed: those
        regress the normal directly, and without plane fits."""
        return cls(
            tuple(int(w) for w in config["encoder"]),
            tuple(int(w) for w in config["regressor"]),
            bool(config.get("residual", False)),
            tuple(int(m) for m in config.get("scales", ())),
            tuple(int(m) for m in config.get("inlier_seeds", ())),
        )

    def forward(self, patches: torch.Tensor, fits: ScaleFits | None = None) -> torch.Tensor:
        return self.regressor(self.encoder(patches), fits)

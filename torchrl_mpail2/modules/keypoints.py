r"""Spatial soft-argmax keypoints: an image coder head whose features move with the objects they find.

Not in the paper (its CNN coder flattens the last feature map, Fig. 14); the head of visuomotor policies since
Levine et al. (2016) and robomimic's image encoders. Each of :math:`K` feature maps :math:`h_k \in \mathbb{R}^{h
\times w}`, standardised over its cells, becomes a distribution over them and yields its expected image coordinates

.. math:: p_k(i, j) = \operatorname{softmax}_{(i, j)}\!\Big(\frac{h_k(i, j) - \mu_k}{\sigma_k\,\tau}\Big), \qquad
          (\bar x_k, \bar y_k) = \sum_{i, j} p_k(i, j)\,(x_j, y_i), \quad x_j, y_i \in [-1, 1],

with :math:`\mu_k, \sigma_k` the map's mean and standard deviation over its cells and a learned temperature
:math:`\tau`. The standardisation makes the keypoints follow what stands out in each map from the first update,
whatever the scale of the untrained maps (a dot moved across an empty 64 x 64 picture: every keypoint of a
Kaiming-initialised coder moved with it, correlation 0.6-0.95; without it, at :math:`\tau = 1`, they moved by 1% of
the picture). A flattened map gives two positions of a small object (a cube, the point
mass) latents that differ alike however far apart the positions are; a keypoint moves by about as much as the object
does, so that distances in the picture become distances in the latent (the geometry the critic's gradient climbs).
"""
from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["STD_FLOOR", "SpatialSoftmax"]

#: Floor of a map's standard deviation over its cells: a flat map (nothing found) gives near-uniform probabilities.
STD_FLOOR = 1e-4


class SpatialSoftmax(nn.Module):
    """``[*B, K, h, w]`` feature maps -> ``[*B, 2K]`` expected coordinates ``(x_1, y_1, ..., x_K, y_K)`` in [-1, 1].

    Args:
        init_temperature (float): the softmax temperature :math:`\\tau` at initialisation (learned, kept positive
            through its logarithm).

    Examples:
        >>> maps = torch.zeros(1, 1, 5, 5)
        >>> maps[0, 0, 1, 4] = 1e3  # row 1, column 4: x = 1, y = -0.5
        >>> SpatialSoftmax(init_temperature=0.1)(maps)  # a sharp softmax: the peak's cell
        tensor([[ 1.0000, -0.5000]], grad_fn=<ViewBackward0>)
    """

    def __init__(self, init_temperature: float = 1.0):
        super().__init__()
        if not init_temperature > 0:
            raise ValueError(f"SpatialSoftmax: init_temperature must be positive, got {init_temperature}")
        self.log_temperature = nn.Parameter(torch.tensor(float(init_temperature)).log())

    def forward(self, maps: Tensor) -> Tensor:
        if maps.dim() < 3:
            raise ValueError(f"SpatialSoftmax expects [*B, K, h, w] feature maps, got shape {list(maps.shape)}")
        *batch, k, h, w = maps.shape
        # float32 whatever the autocast dtype: bf16 sums of h * w probabilities lose the coordinates
        cells = maps.float().reshape(*batch, k, h * w)
        std, mean = torch.std_mean(cells, dim=-1, keepdim=True)
        logits = (cells - mean) / (std.clamp_min(STD_FLOOR) * self.log_temperature.exp())
        probs = torch.softmax(logits, dim=-1)
        ys, xs = torch.meshgrid(torch.linspace(-1.0, 1.0, h, device=maps.device),
                                torch.linspace(-1.0, 1.0, w, device=maps.device), indexing="ij")
        grid = torch.stack([xs.reshape(-1), ys.reshape(-1)], dim=-1)  # [h * w, 2]: (x, y) of each cell
        return (probs @ grid).reshape(*batch, 2 * k)

r"""Observation encoder :math:`e_\omega : o \mapsto z` (Section 3, Fig. 14 and Figs. 16-17).

Vector keys go through MLP coders, 64x64 RGB keys through the paper's CNN coder; the coders'
outputs are either fused by a latent MLP (default) or kept as one latent block per key
(compartmentalised, so that a reward can read a subset of the latent).
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from torchrl_mpail2.modules._mlp import mlp
from torchrl_mpail2.modules.keypoints import SpatialSoftmax

IMAGE_SIZE = 64
IMAGE_CHANNELS = 3
#: Pixel normalisations (``ModelConfig.image_norm``): ``centred`` x / 255 - 0.5 (the authors' code), ``demos`` per
#: pixel and channel standardised by the demonstrations' statistics (:meth:`EncoderNet.set_normalization`).
IMAGE_NORMS = ("centred", "demos")
#: Floor of the per-pixel std of ``image_norm="demos"`` (pixel values in [0, 1]; about five grey levels): pixels the
#: demonstrations never change (the table, the wall) would otherwise divide by zero.
PIXEL_STD_FLOOR = 0.02
#: Initialisations of the image coder (``ModelConfig.cnn_init``): ``torch`` PyTorch's defaults, ``kaiming``
#: Kaiming-normal weights (fan in, ReLU gain) and zero biases for the convolutions and the coder's Linear.
CNN_INITS = ("torch", "kaiming")
#: Heads of the image coder (``ModelConfig.image_head``): ``flatten`` the last feature map (Fig. 14), ``keypoints``
#: a 1x1 convolution to ``ModelConfig.keypoints`` maps and their spatial soft-argmax (:mod:`.keypoints`).
IMAGE_HEADS = ("flatten", "keypoints")
_CNN_STRIDES = (2, 2, 2, 1)
_CNN_KERNEL = 3


def is_image_shape(shape: Sequence[int]) -> bool:
    """True for channels-first RGB images ``[3, H, W]``."""
    return len(shape) == 3 and shape[0] == IMAGE_CHANNELS


class VectorCoder(nn.Sequential):
    """``Linear -> SiLU -> Linear -> LayerNorm -> SiLU`` (Fig. 14, ``Coder``)."""

    def __init__(self, in_dim: int, hidden: int, out_dim: int):
        super().__init__(nn.Linear(in_dim, hidden), nn.SiLU(), nn.Linear(hidden, out_dim), nn.LayerNorm(out_dim), nn.SiLU())


class ImageCoder(nn.Module):
    """Four 3x3 convolutions (strides 2, 2, 2, 1, SiLU), flatten, ``Linear -> SiLU`` (Fig. 14, ``CNNCoder``).

    Accepts uint8 images in ``[0, 255]`` or float images in ``[0, 1]``, channels first ``[*B, 3, H, W]``, and
    standardises them by the buffers ``pixel_mean`` and ``pixel_std`` (0.5 and 1: the authors' centring, unless
    :meth:`EncoderNet.set_normalization` set them from demonstrations), clipped at ``clip``. The images go to
    the convolutions channels-last, oneDNN's fast layout (one thread of a 2-core AMD EPYC: a stop-gradient encode 2.1
    times faster than all-NCHW; weights held channels-last as well gained nothing more,
    ``benchmarks/speed/cnn_layout_speed.py``); the result is the channels-first computation's up to float rounding
    (``tests/test_modules.py``).

    ``head="keypoints"`` (:data:`IMAGE_HEADS`) replaces the flatten by ``keypoints`` spatial soft-argmax coordinates
    of the last feature map (5 x 5 for 64 x 64 inputs): ``Conv1x1 -> SpatialSoftmax -> Linear -> SiLU``.

    ``init="kaiming"`` (:data:`CNN_INITS`) keeps the scale of the pictures' differences through the layers: with
    PyTorch's defaults each layer shrinks them, and the coder's outputs (rms 0.02 for the point mass) fall below the
    fusion layer's biases (rms 0.08), so that the latents of all pictures nearly coincide.
    """

    def __init__(self, image_shape: Sequence[int], channels: int, out_dim: int, clip: float = 5.0,
                 init: str = "torch", head: str = "flatten", keypoints: int = 32):
        super().__init__()
        if head not in IMAGE_HEADS:
            raise ValueError(f"unknown image coder head {head!r}; choose from {IMAGE_HEADS}")
        self.clip, self.head = clip, head
        self.register_buffer("pixel_mean", torch.full(tuple(image_shape), 0.5))
        self.register_buffer("pixel_std", torch.ones(tuple(image_shape)))
        layers: list[nn.Module] = []
        in_ch = image_shape[0]
        for stride in _CNN_STRIDES:
            layers += [nn.Conv2d(in_ch, channels, _CNN_KERNEL, stride=stride), nn.SiLU()]
            in_ch = channels
        if head == "flatten":
            self.convs = nn.Sequential(*layers, nn.Flatten())
        else:  # the keypoints of the last feature map: [K, h, w] -> [2K]
            self.convs = nn.Sequential(*layers, nn.Conv2d(channels, keypoints, 1), SpatialSoftmax())
        with torch.no_grad():
            maps = nn.Sequential(*layers)(torch.zeros(1, *image_shape))
            flat = self.convs[len(layers):](maps).shape[-1]  # flatten: 800 for 64x64 inputs
        self.map_size = int(maps.shape[-1])  #: side of the last feature map (5 for 64x64 inputs)
        self.out = nn.Sequential(nn.Linear(flat, out_dim), nn.SiLU())
        if init == "kaiming":
            for layer in (*self.convs, self.out[0]):
                if isinstance(layer, (nn.Conv2d, nn.Linear)):
                    nn.init.kaiming_normal_(layer.weight, nonlinearity="relu")
                    nn.init.zeros_(layer.bias)
        elif init != "torch":
            raise ValueError(f"unknown image coder init {init!r}; choose from {CNN_INITS}")

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints written before the pixel statistics were buffers centred pixels: load them as they ran
        for name, fill in (("pixel_mean", 0.5), ("pixel_std", 1.0)):
            state_dict.setdefault(prefix + name, torch.full_like(getattr(self, name), fill))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _normalised(self, image: Tensor) -> Tensor:
        r"""``[*B, 3, H, W]`` -> ``[N, 3, H, W]`` channels-last, standardised and clipped.

        :math:`\operatorname{clip}((x / 255 - \mu) / \sigma) = \operatorname{clip}(x \cdot a + b)` with
        :math:`a = 1 / (255\,\sigma)` and :math:`b = -\mu / \sigma` per pixel: one fused pass over the frames
        after their conversion to float, rather than four (profiled over one update of the ``push_pixels`` networks
        on one thread: 12-15% of its time in the four passes, about 3% in the fused one; ``tests/test_modules.py``
        holds the two forms equal up to float rounding).
        """
        x = image.reshape(-1, *image.shape[-3:]).contiguous(memory_format=torch.channels_last)
        scale = self.pixel_std.reciprocal()
        if not torch.is_floating_point(x):
            x, scale = x.float(), scale / 255.0
        # per-pixel factors laid out as the frames are, so that the fused pass runs over contiguous memory
        scale = scale.unsqueeze(0).contiguous(memory_format=torch.channels_last)
        shift = (-self.pixel_mean / self.pixel_std).unsqueeze(0).contiguous(memory_format=torch.channels_last)
        return torch.addcmul(shift, x, scale).clamp_(-self.clip, self.clip)

    def forward(self, image: Tensor) -> Tensor:
        y = self.out(self.convs(self._normalised(image)))
        return y.reshape(*image.shape[:-3], -1)

    def keypoints(self, image: Tensor) -> Tensor:
        """The ``keypoints`` head's coordinates ``[*B, K, 2]`` (x right, y down, in [-1, 1] over the last feature
        map's cells) of ``[*B, 3, H, W]`` images.

        Raises:
            ValueError: a coder with the ``flatten`` head.
        """
        if self.head != "keypoints":
            raise ValueError("this image coder flattens its feature map (model.image_head=flatten): no keypoints")
        return self.convs(self._normalised(image)).reshape(*image.shape[:-3], -1, 2)


class EncoderNet(nn.Module):
    """Tensor-level encoder: ``forward(*observations) -> z`` in the order of ``keys``.

    Args:
        observation_shapes (Mapping[str, Sequence[int]]): per-key shapes (vector ``[D]`` or image ``[3, 64, 64]``).
        latent_dim (int): ``Z`` (fused mode) or the total of the per-key blocks (compartmentalised).
        hidden_dims (Sequence[int]): hidden widths of the fusion MLP.
        vector_coder_hidden (int): hidden width of vector coders.
        coder_dim (int): output width of each coder.
        cnn_channels (int): channels of the image coder.
        fuse_latent (bool): fused (True) or compartmentalised (False) latent.
        obs_clip (float): clip of normalised vector observations.
        cnn_init (str): initialisation of the image coders (:data:`CNN_INITS`).
        image_head (str): head of the image coders (:data:`IMAGE_HEADS`).
        keypoints (int): keypoints of the ``keypoints`` head.
    """

    def __init__(self, observation_shapes: Mapping[str, Sequence[int]], latent_dim: int, hidden_dims: Sequence[int],
                 vector_coder_hidden: int = 256, coder_dim: int = 512, cnn_channels: int = 32,
                 fuse_latent: bool = True, obs_clip: float = 5.0, cnn_init: str = "torch",
                 image_head: str = "flatten", keypoints: int = 32):
        super().__init__()
        if not observation_shapes:
            raise ValueError("the encoder needs at least one observation key")
        self.keys = list(observation_shapes)
        self.shapes = {k: tuple(int(s) for s in v) for k, v in observation_shapes.items()}
        self.latent_dim, self.fuse_latent, self.obs_clip = latent_dim, fuse_latent, obs_clip
        self.coders = nn.ModuleDict()
        for key, shape in self.shapes.items():
            if is_image_shape(shape):
                self.coders[key] = ImageCoder(shape, cnn_channels, coder_dim, clip=obs_clip, init=cnn_init,
                                              head=image_head, keypoints=keypoints)
            elif len(shape) == 1:
                self.coders[key] = VectorCoder(shape[0], vector_coder_hidden, coder_dim)
                self.register_buffer(f"obs_mean_{key}", torch.zeros(shape))
                self.register_buffer(f"obs_std_{key}", torch.ones(shape))
            else:
                raise ValueError(f"observation {key!r}: expected a vector [D] or an image [3, 64, 64], got {list(shape)}")
        if fuse_latent:
            self.latent_coder = mlp(coder_dim * len(self.keys), hidden_dims, latent_dim, out_norm=True)
            self.latent_slices = {k: slice(0, latent_dim) for k in self.keys}
        else:
            # One LayerNorm'd block per key; blocks split latent_dim as evenly as possible.
            sizes = [latent_dim // len(self.keys) + (i < latent_dim % len(self.keys)) for i in range(len(self.keys))]
            if min(sizes) == 0:
                raise ValueError(f"latent_dim {latent_dim} is too small for {len(self.keys)} compartments")
            self.blocks = nn.ModuleDict({k: nn.Sequential(nn.Linear(coder_dim, n), nn.LayerNorm(n)) for k, n in zip(self.keys, sizes)})
            starts = [sum(sizes[:i]) for i in range(len(sizes))]
            self.latent_slices = {k: slice(s, s + n) for k, s, n in zip(self.keys, starts, sizes)}

    @property
    def vector_keys(self) -> list[str]:
        return [k for k in self.keys if len(self.shapes[k]) == 1]

    def set_normalization(self, stats: Mapping[str, tuple[Tensor, Tensor]]) -> None:
        """Sets the fixed (mean, std) of vector keys, or of image keys (per pixel and channel ``[3, H, W]``, pixel
        values in [0, 1]; the std floored at :data:`PIXEL_STD_FLOOR`), e.g. from demonstration statistics."""
        for key, (mean, std) in stats.items():
            if key not in self.keys:
                raise KeyError(f"no observation {key!r} to normalise; keys: {self.keys}")
            if key not in self.vector_keys:
                coder = self.coders[key]
                mean, std = torch.as_tensor(mean, dtype=torch.float32), torch.as_tensor(std, dtype=torch.float32)
                if mean.shape != coder.pixel_mean.shape or std.shape != coder.pixel_mean.shape:
                    raise ValueError(f"normalisation of {key!r}: expected shape {list(coder.pixel_mean.shape)}, got "
                                     f"mean {list(mean.shape)}, std {list(std.shape)}")
                coder.pixel_mean.copy_(mean)
                coder.pixel_std.copy_(std.clamp_min(PIXEL_STD_FLOOR))
                continue
            buf = getattr(self, f"obs_mean_{key}")
            mean, std = torch.as_tensor(mean, dtype=buf.dtype), torch.as_tensor(std, dtype=buf.dtype)
            if mean.shape != buf.shape or std.shape != buf.shape:
                raise ValueError(f"normalisation of {key!r}: expected shape {list(buf.shape)}, got mean {list(mean.shape)}, std {list(std.shape)}")
            buf.copy_(mean)
            getattr(self, f"obs_std_{key}").copy_(std.clamp_min(1e-6))

    def encode_key(self, key: str, x: Tensor) -> Tensor:
        if len(self.shapes[key]) == 1:
            mean, std = getattr(self, f"obs_mean_{key}"), getattr(self, f"obs_std_{key}")
            x = ((x - mean) / std).clamp(-self.obs_clip, self.obs_clip)
        return self.coders[key](x)

    def encode_blocks(self, observations: Mapping[str, Tensor]) -> Tensor:
        """``z [*B, Z]`` of some of the keys (compartmentalised latent only): their blocks, zeros in the blocks of
        the keys not given. For observations that hold only some keys (video-only demonstrations), read by a reward
        that selects the given keys' blocks.

        Raises:
            ValueError: on a fused latent (every latent dimension depends on every key), or an unknown key.
        """
        if self.fuse_latent:
            raise ValueError("encode_blocks needs a compartmentalised latent (fuse_latent=False)")
        unknown = [key for key in observations if key not in self.latent_slices]
        if unknown:
            raise ValueError(f"observation keys {unknown} are not encoder keys {self.keys}")
        first = next(iter(observations.values()))
        batch = first.shape[: first.dim() - len(self.shapes[next(iter(observations))])]
        z = first.new_zeros(*batch, self.latent_dim, dtype=torch.get_default_dtype())
        for key, x in observations.items():
            z[..., self.latent_slices[key]] = self.blocks[key](self.encode_key(key, x))
        return z

    def forward(self, *observations: Tensor) -> Tensor:
        """Observations ordered as ``keys`` (each ``[*B, *shape]``) -> ``z [*B, Z]``."""
        feats = [self.encode_key(k, x) for k, x in zip(self.keys, observations)]
        if self.fuse_latent:
            return self.latent_coder(torch.cat(feats, dim=-1))
        return torch.cat([self.blocks[k](f) for k, f in zip(self.keys, feats)], dim=-1)


def validate_observations(td: TensorDictBase, shapes: Mapping[str, Sequence[int]], where: str = "observation") -> None:
    """Raises a clear error when a key is missing, has the wrong trailing shape, or holds NaN/Inf.

    One host sync per call: meant for inputs entering the agent (acting, demonstrations), not for inner loops.
    """
    for key, shape in shapes.items():
        value = td.get(key, None)
        if value is None:
            raise KeyError(f"{where}: missing key {key!r} (expected shape [*B, {', '.join(map(str, shape))}]); present: {list(td.keys(True, True))}")
        if tuple(value.shape[value.dim() - len(shape):]) != tuple(shape) or value.dim() < len(shape):
            raise ValueError(f"{where} {key!r}: expected shape [*B, {', '.join(map(str, shape))}], got {list(value.shape)}")
        if torch.is_floating_point(value) and not bool(torch.isfinite(value).all()):
            raise ValueError(f"{where} {key!r} contains NaN or Inf values")


class ObservationEncoder(TensorDictModuleBase):
    r"""Encoder :math:`z_t = e_\omega(o_t)` as a TensorDict module (reads the observation keys, writes ``"z"``).

    Trained only through the JEP dynamics loss (Eq. 2) in MPAIL2.

    Args:
        observation_shapes (Mapping[str, Sequence[int]]): per-key shapes; see :class:`EncoderNet`.
        latent_dim (int): ``Z``.
        hidden_dims (Sequence[int]): fusion MLP widths.

    Keyword Args:
        out_key: defaults to ``"z"``.
        **kwargs: forwarded to :class:`EncoderNet`.

    Examples:
        >>> from tensordict import TensorDict
        >>> enc = ObservationEncoder({"proprio": [8], "camera": [3, 64, 64]}, latent_dim=16, hidden_dims=[32],
        ...                          coder_dim=32, vector_coder_hidden=32)
        >>> td = TensorDict({"proprio": torch.zeros(2, 8), "camera": torch.zeros(2, 3, 64, 64, dtype=torch.uint8)}, [2])
        >>> enc(td)["z"].shape
        torch.Size([2, 16])
    """

    def __init__(self, observation_shapes: Mapping[str, Sequence[int]], latent_dim: int, hidden_dims: Sequence[int], *,
                 out_key="z", **kwargs):
        super().__init__()
        self.net = EncoderNet(observation_shapes, latent_dim, hidden_dims, **kwargs)
        self.in_keys = list(self.net.keys)
        self.out_keys = [out_key]

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        return dict(self.net.shapes)

    def encode(self, td: TensorDictBase, prefix: tuple[str, ...] = ()) -> Tensor:
        """Encodes the observation keys found under ``prefix`` (e.g. ``("next",)``) without validation."""
        return self.net(*(td.get((*prefix, k)) for k in self.in_keys))

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        validate_observations(tensordict, self.net.shapes)
        tensordict.set(self.out_keys[0], self.encode(tensordict))
        return tensordict

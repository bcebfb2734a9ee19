"""LPIPS (Zhang et al. 2018, v0.1) without torchvision.

The trunk is written here with torchvision's module layout, so torchvision's
own ImageNet weights (``alexnet-owt-7be5be79.pth``, ``vgg16-397923af.pth``)
load into it by their key names (``features.0.weight`` ...); the linear
layers take the official ``lpips/weights/v0.1/{alex,vgg}.pth`` of
richzhang/PerceptualSimilarity (keys ``lin0.model.1.weight`` ...). Both files
are pickles: they are read with ``torch.load(weights_only=True)`` only, which
refuses anything but tensors and plain containers.

Forward, as ``lpips.LPIPS(net=..., version="0.1")``: inputs (B, 3, H, W) in
[-1, 1]; the scaling layer ``(x − shift) / scale`` with shift (−0.030, −0.088,
−0.188), scale (0.458, 0.448, 0.450); the trunk's ReLU outputs at five taps;
each unit-normalised over channels (ε = 1e-10); squared difference; a 1×1
convolution without bias (the linear layer); the spatial mean; summed over
taps. Returns (B, 1, 1, 1).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from .common import MetricInputError

__all__ = ["LPIPS", "alexnet_features", "vgg16_features", "TAPS", "CHANNELS", "load_pth_state_dict"]

#: ReLU indices in ``features`` whose outputs LPIPS compares (lpips/pretrained_networks.py slices).
TAPS = {"alex": (1, 4, 7, 9, 11), "vgg": (3, 8, 15, 22, 29)}
CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}
_VGG16 = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M")


def alexnet_features() -> nn.Sequential:
    """torchvision's ``AlexNet().features`` (same indices, shapes and parameter names)."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2),
        nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2),
        nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1),
        nn.ReLU(inplace=False),
        nn.Conv2d(384, 256, kernel_size=3, padding=1),
        nn.ReLU(inplace=False),
        nn.Conv2d(256, 256, kernel_size=3, padding=1),
        nn.ReLU(inplace=False),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


def vgg16_features() -> nn.Sequential:
    """torchvision's ``vgg16().features`` (configuration "D", no batch norm)."""
    layers: list[nn.Module] = []
    c = 3
    for v in _VGG16:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(c, v, kernel_size=3, padding=1), nn.ReLU(inplace=False)]
            c = v
    return nn.Sequential(*layers)


def load_pth_state_dict(path) -> dict:
    """A ``.pth`` state dict read with ``torch.load(weights_only=True)`` (tensors only; no code runs)."""
    p = Path(path)
    if not p.is_file():
        raise MetricInputError(p, "file", "an existing .pth weights file", "no such file")
    try:
        data = torch.load(str(p), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - an unpickling error has many types
        raise MetricInputError(
            p,
            "contents",
            "a state dict of tensors (torch.load weights_only=True)",
            f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
        ) from None
    if not isinstance(data, dict) or not all(isinstance(v, torch.Tensor) for v in data.values()):
        raise MetricInputError(p, "contents", "a mapping of parameter names to tensors", type(data).__name__)
    return data


class LPIPS(nn.Module):
    """The LPIPS v0.1 distance with an AlexNet (``net="alex"``) or VGG-16 (``"vgg"``) trunk.

    ``forward(x, y)``: (B, 3, H, W) in [-1, 1] each → (B, 1, 1, 1) distances.
    Weights: :meth:`load_trunk` (torchvision key names) and :meth:`load_linear`
    (the official linear layers), or :meth:`from_files`.
    """

    def __init__(self, net: str = "alex"):
        super().__init__()
        if net not in TAPS:
            raise MetricInputError("net", "value", f"one of {sorted(TAPS)}", repr(net))
        self.net_name = net
        self.features = alexnet_features() if net == "alex" else vgg16_features()
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in CHANNELS[net])
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    @classmethod
    def from_files(cls, net: str, trunk, linear) -> LPIPS:
        model = cls(net)
        model.load_trunk(load_pth_state_dict(trunk), source=str(trunk))
        model.load_linear(load_pth_state_dict(linear), source=str(linear))
        return model

    def load_trunk(self, state: dict, source: str = "trunk") -> None:
        """Load torchvision's classifier weights: every ``features.*`` key must match; ``classifier.*`` is unused."""
        feats = {k[len("features.") :]: v for k, v in state.items() if k.startswith("features.")}
        other = sorted(k for k in state if not k.startswith(("features.", "classifier.")))
        if other:
            raise MetricInputError(source, "keys", "torchvision keys features.* / classifier.*", f"unknown {other[:5]}")
        self._load(self.features, feats, source, "features.")

    def load_linear(self, state: dict, source: str = "linear") -> None:
        """Load ``lin{k}.model.1.weight`` (the official file; ``lin{k}.model.0`` is the unused dropout)."""
        for k, lin in enumerate(self.lins):
            key = f"lin{k}.model.1.weight"
            if key not in state:
                raise MetricInputError(
                    source, key, f"a ({CHANNELS[self.net_name][k]}-channel) linear layer", "no such key"
                )
            self._load(lin, {"weight": state[key]}, source, f"lin{k}.model.1.")

    @staticmethod
    def _load(module: nn.Module, state: dict, source: str, prefix: str) -> None:
        expected = module.state_dict()
        missing = sorted(set(expected) - set(state))
        extra = sorted(set(state) - set(expected))
        if missing or extra:
            raise MetricInputError(
                source,
                "keys",
                f"exactly {[prefix + k for k in sorted(expected)][:6]}...",
                f"missing {[prefix + k for k in missing][:5]}, extra {[prefix + k for k in extra][:5]}",
            )
        for k, v in state.items():
            if tuple(v.shape) != tuple(expected[k].shape):
                raise MetricInputError(source, prefix + k, f"shape {tuple(expected[k].shape)}", f"{tuple(v.shape)}")
        module.load_state_dict({k: v.float() for k, v in state.items()}, strict=True)

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        taps = TAPS[self.net_name]
        x, y = (x - self.shift) / self.scale, (y - self.shift) / self.scale
        total = 0.0
        k = 0
        for i, layer in enumerate(self.features):
            x, y = layer(x), layer(y)
            if i in taps:
                nx = x / (torch.sqrt((x**2).sum(dim=1, keepdim=True)) + 1e-10)
                ny = y / (torch.sqrt((y**2).sum(dim=1, keepdim=True)) + 1e-10)
                total = total + self.lins[k]((nx - ny) ** 2).mean(dim=(2, 3), keepdim=True)
                k += 1
                if k == len(taps):
                    break
        return total

"""Point-wise layers of the gate networks: 1x1 convolutions as matrix products, BatchNorm folded at inference.

A 1x1 ``Conv2d`` on (B, C, N, k) neighbourhood tensors runs torch's im2col path on the CPU; the same
product as one ``W @ x`` is 2.3x faster (0.28 against 0.65 ms for 16 -> 16 channels on 1024 x 16, one
core), and folding an eval-mode BatchNorm into the weights saves its own pass (another 0.22 ms there).
Measured with benchmarks/gate_speed.py's setting (torch.set_num_threads(1)).

Each layer works channels-first (``forward``: dim 1, as the networks' state dicts were written) and
channels-last (``last``: the last dim, one ``F.linear`` on contiguous rows, what CurveNet uses so that
neighbour gathers are row gathers). A network that splits a layer's input into parts (a linear map of a
concatenation is the sum of the parts' maps) takes :meth:`ConvBN.folded` and :meth:`ConvBN.normalize`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["ConvBN", "Pointwise", "sequential_last"]


class Pointwise(nn.Module):
    """1x1 convolution over dim 1: (B, C_in, *) -> (B, C_out, *); weight (C_out, C_in), optional bias."""

    def __init__(self, c_in: int, c_out: int, *, bias: bool = False) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(c_out, c_in))
        self.bias = nn.Parameter(torch.empty(c_out)) if bias else None
        # torch's Conv/Linear default initialization, so the networks start as their Conv versions would
        nn.init.kaiming_uniform_(self.weight, a=math.sqrt(5))
        if self.bias is not None:
            nn.init.uniform_(self.bias, -1 / math.sqrt(c_in), 1 / math.sqrt(c_in))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return _apply(x, self.weight, self.bias)

    def last(self, x: torch.Tensor) -> torch.Tensor:
        """The same map over the last dim: (..., C_in) -> (..., C_out)."""
        return F.linear(x, self.weight, self.bias)


class ConvBN(nn.Module):
    """1x1 convolution (no bias) then BatchNorm over dim 1: (B, C_in, *) -> (B, C_out, *).

    Training: batch statistics as usual. Eval: the running statistics folded into one affine product.
    """

    def __init__(self, c_in: int, c_out: int) -> None:
        super().__init__()
        self.conv = Pointwise(c_in, c_out)
        self.bn = nn.BatchNorm1d(c_out)
        self._folded: tuple[tuple, tuple[torch.Tensor, torch.Tensor]] | None = None  # see folded()
        self._derived: dict[str, tuple[torch.Tensor, Any]] = {}  # see derived()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training:
            flat = self.bn(self.conv(x.flatten(2)))
            return flat.view(x.shape[0], -1, *x.shape[2:])
        return _apply(x, *self.folded())

    def last(self, x: torch.Tensor) -> torch.Tensor:
        """The same layer over the last dim: (..., C_in) -> (..., C_out)."""
        weight, bias = self.folded()
        out = F.linear(x, weight)
        if bias is not None:  # added in place: F.linear's fused bias path is slower on one core (measured
            out.add_(bias)  # 140 against 90 us for 12288 rows of 8 -> 8, and a 390 kB temporary fewer)
        return self.normalize(out)

    def folded(self) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The layer's linear part: weight (C_out, C_in) and bias (C_out,). Eval: BatchNorm folded in, so
        ``x @ weight.T + bias`` is the whole layer. Training: the convolution's weight and no bias; the
        BatchNorm (batch statistics) comes after, through :meth:`normalize`.

        Without gradients (inference) the fold is kept until a parameter or running statistic changes
        (the version counter of any of them, or the weight's storage: ``load_state_dict``, optimizer steps,
        in-place writes, ``.to``; a write through ``.data`` is not seen): 7 small operations per layer and
        call saved, ~0.5 ms of CurveNet's inference on one core (benchmarks/gate_speed.py).
        """
        if self.training:
            return self.conv.weight, None
        if torch.is_grad_enabled():  # gradients may be wanted through the fold: no cache
            return self._fold()
        # the tensors straight from the modules' dicts: nn.Module.__getattr__ costs ~1 us a lookup, and this runs
        # ~50 times per CurveNet inference (6 lookups each: ~0.3 ms of ~10)
        weight = self._modules["conv"]._parameters["weight"]
        bn = self._modules["bn"]
        params, buffers = bn._parameters, bn._buffers
        key = (
            weight.data_ptr(),
            weight._version,
            params["weight"]._version,
            params["bias"]._version,
            buffers["running_mean"]._version,
            buffers["running_var"]._version,
        )
        if self._folded is None or self._folded[0] != key:
            with torch.inference_mode(False), torch.no_grad():  # ordinary tensors: usable outside inference mode
                self._folded = (key, self._fold())
        return self._folded[1]

    def derived(self, name: str, make: Callable[[torch.Tensor, torch.Tensor | None], Any]) -> Any:
        """``make(*self.folded())``: constants a network derives from the layer's linear part (weight
        slices and sums, numpy copies). At inference (eval, no gradients) computed once and kept with the
        fold (renewed when the fold is: :meth:`folded`), so a forward pass does not redo those small
        operations: ~10 tensor calls per layer and call (CurveNet's LPFA geometry and walk policy)."""
        weight, bias = self.folded()
        if self.training or torch.is_grad_enabled():
            return make(weight, bias)
        entry = self._derived.get(name)
        if entry is None or entry[0] is not weight:  # the fold's tensors are new whenever it was renewed
            with torch.inference_mode(False), torch.no_grad():
                entry = self._derived[name] = (weight, make(weight, bias))
        return entry[1]

    def _fold(self) -> tuple[torch.Tensor, torch.Tensor]:
        bn = self.bn
        scale = bn.weight / torch.sqrt(bn.running_var + bn.eps)
        return self.conv.weight * scale[:, None], bn.bias - bn.running_mean * scale

    def normalize(self, pre: torch.Tensor) -> torch.Tensor:
        """(..., C_out) output of :meth:`folded`'s linear map -> the layer's output: the BatchNorm with batch
        statistics over every leading position in training, nothing in eval (already folded)."""
        if not self.training:
            return pre
        return self.bn(pre.reshape(-1, pre.shape[-1])).view(pre.shape)


def _apply(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    out = weight @ x.flatten(2)  # (C_out, C_in) @ (B, C_in, L): one broadcast product, no copies of the input
    if bias is not None:
        out = out + bias[:, None]
    return out.view(x.shape[0], -1, *x.shape[2:])


def sequential_last(layers: Iterable[nn.Module], x: torch.Tensor, *, fresh: bool = False) -> torch.Tensor:
    """:class:`ConvBN` / :class:`Pointwise` layers and element-wise activations (a Sequential's) applied over
    the last dim of x: (..., C_in) -> (..., C_out). An activation after a layer runs in place on that layer's
    output (a fresh tensor; the backward passes of a linear map and of BatchNorm do not read their output):
    one large temporary fewer per activation, which on the CPU is a fresh allocation and its page faults.
    ``fresh``: x itself may be overwritten (the caller made it and does not read it again)."""
    for layer in layers:
        if isinstance(layer, ConvBN | Pointwise):
            x, fresh = layer.last(x), True
        elif fresh and isinstance(layer, nn.LeakyReLU):
            x = F.leaky_relu_(x, layer.negative_slope)
        elif fresh and isinstance(layer, nn.ReLU):
            x = torch.relu_(x)
        else:
            x, fresh = layer(x), False
    return x

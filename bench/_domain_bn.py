"""Domain-specific batch normalization (DSBN, Chang et al., CVPR 2019) for the arms of
bench/perception.py that see real and synthetic frames (``--domain-bn``).

Why: in a mixed batch every BN layer normalizes real frames with statistics partly of synthetic
ones, and the statistics kept for evaluation are a blend of both; AdaBN (``--bn-stats real``)
only fixes the kept statistics after training. Here every ``BatchNorm2d`` becomes a pair, one for
real frames and one for synthetic ones (statistics *and* affine weights; the synthetic one starts
as a copy of the network's own, e.g. ImageNet's), the convolutions stay shared. A batch is real
frames first, then synthetic ones (bench/_perception_train.py builds it in that order), so each
layer normalizes ``x[:n_real]`` with the real pair and the rest with the synthetic one.
Evaluation uses the real pair only. The pretrain arm (b) trains the synthetic pair in phase 1
and the real pair in phase 2.
"""
from __future__ import annotations

import copy


class DomainSplit:
    """How many frames at the head of the next training batch are real (None: all of them)."""

    def __init__(self) -> None:
        self.n_real: int | None = None


def _module_class():
    import torch

    class DomainBatchNorm(torch.nn.Module):
        """A BN for real frames and one for synthetic frames; evaluation: the real one."""

        def __init__(self, bn, split: DomainSplit):
            super().__init__()
            self.real, self.synth = bn, copy.deepcopy(bn)
            self.split = split

        def forward(self, x):
            n = self.split.n_real
            if not self.training or n is None or n >= x.shape[0]:
                return self.real(x)
            if n <= 0:
                return self.synth(x)
            return torch.cat([self.real(x[:n]), self.synth(x[n:])])

    return DomainBatchNorm


def split_batchnorms(model) -> DomainSplit:
    """Replace every BatchNorm2d of ``model`` (in place) by a real / synthetic pair sharing one
    :class:`DomainSplit`, which the caller sets before each training step; returns it."""
    import torch

    cls, split = _module_class(), DomainSplit()
    for parent in list(model.modules()):
        for name, child in list(parent.named_children()):
            if isinstance(child, torch.nn.BatchNorm2d):
                setattr(parent, name, cls(child, split))
    model.domain_split = split
    return split


def set_real_count(model, n_real: int | None) -> None:
    """Tell a model with domain BNs how many frames at the head of the next batch are real; a
    model without them is left alone."""
    split = getattr(model, "domain_split", None)
    if split is not None:
        split.n_real = n_real

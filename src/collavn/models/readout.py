"""Perception readout: the pretraining heads, kept in the agent as an input to its policy.

``collavn pretrain`` teaches the frame perception labels the simulator knows (see
:mod:`collavn.perception.labels`) through these heads. Deliberately shallow — linear on
``o`` for free space, one hidden layer on ``[o, g]`` for the pair labels — so what they
read must be nearly linear in the embeddings. With ``ReadoutConfig.enabled`` the heads
are part of :class:`~collavn.models.frames.FramePerception` and :meth:`features` joins
the goal embedding: the policy gets "the path leaves through sector k" as a probability
vector, so turning towards it is a linear function of its input. An imitation learner
that has to find that function in the raw embeddings averages the oracle's left and
right turns into driving straight (measured: its mean action almost never turned).
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

#: The labels, in the order they are reported.
LABELS = ("path_bearing", "goal_bearing", "distance", "free_space")


class PerceptionReadout(nn.Module):
    """Predict the pretraining labels from ``o (B, embed)`` and ``g (B, goal)``."""

    def __init__(self, embed_size: int, goal_size: int, bins: int, hidden: int) -> None:
        super().__init__()
        self.free = nn.Linear(embed_size, bins)
        self.pair = nn.Sequential(nn.Linear(embed_size + goal_size, hidden), nn.ReLU())
        self.path = nn.Linear(hidden, bins)
        self.goal = nn.Linear(hidden, bins)
        self.distance = nn.Linear(hidden, 1)
        self.bins = bins

    def forward(self, o: Tensor, g: Tensor, ring: Tensor | None = None) -> dict[str, Tensor]:
        """Logits ``(B, K)`` of both bearings, log-distance ``(B,)``, log-free ``(B, K)``.

        ``ring`` (the goal matcher's, :class:`RingReadout`) is not read here.
        """
        h = self.pair(torch.cat([o, g], dim=1))
        return {"path_bearing": self.path(h), "goal_bearing": self.goal(h),
                "distance": self.distance(h).squeeze(-1), "free_space": self.free(o)}

    def features(self, o: Tensor, g: Tensor, ring: Tensor | None = None) -> Tensor:
        """``(B, 3K + 1)``: path and goal sector probabilities, log-distance, log-free."""
        return readout_features(self(o, g, ring))


class RingReadout(nn.Module):
    """The same labels, predicted per azimuth by one circular convolution over the ring.

    The goal matcher's ring (:meth:`~collavn.models.matching.GoalMatcher.match`: every
    feature column's features of all rows, plus the goal's similarity there) goes
    through a residual stack of circular 1-D convolutions (kernel 3, dilations 1, 2, 4, 8:
    each column sees the whole ring), conditioned on ``[o, g]`` by a bias; a 1×1
    convolution gives each column a path logit, a goal logit and a log free space, and a
    sector's value is the mean over its columns. The same weights judge every azimuth, so
    rotating the panorama rotates the prediction: a frame teaches every direction at
    once, where the pooled heads must learn "the path is left" separately for every
    sector. (Measured: the pooled heads' path bearing, turned into a hand controller,
    did not beat the goal-blind explorer on val scenes.) The distance comes from the
    columns' mean and maximum.
    """

    def __init__(self, ring_channels: int, columns: int, embed_size: int, goal_size: int,
                 bins: int, hidden: int) -> None:
        super().__init__()
        if columns % bins:
            raise ValueError(f"readout bins ({bins}) must divide the matcher's {columns} "
                             f"feature columns (panorama width / 4)")
        self.columns, self.bins = columns, bins
        self.context = nn.Linear(embed_size + goal_size, hidden)
        self.inp = nn.Conv1d(ring_channels, hidden, 3, padding=1, padding_mode="circular")
        self.body = nn.ModuleList(nn.Conv1d(hidden, hidden, 3, padding=d, dilation=d,
                                            padding_mode="circular") for d in (2, 4, 8))
        self.out = nn.Conv1d(hidden, 3, 1)
        self.distance = nn.Linear(2 * hidden, 1)

    def forward(self, o: Tensor, g: Tensor, ring: Tensor | None = None) -> dict[str, Tensor]:
        """Logits ``(B, K)`` of both bearings, log-distance ``(B,)``, log-free ``(B, K)``."""
        if ring is None:
            raise ValueError("the ring readout needs the goal matcher's ring "
                             "(model.goal_match.enabled)")
        h = torch.relu(self.inp(ring) + self.context(torch.cat([o, g], dim=1))[:, :, None])
        for conv in self.body:
            h = torch.relu(h + conv(h))
        b = h.shape[0]
        sectors = self.out(h).reshape(b, 3, self.bins, self.columns // self.bins).mean(-1)
        distance = self.distance(torch.cat([h.mean(-1), h.amax(-1)], dim=1)).squeeze(-1)
        return {"path_bearing": sectors[:, 0], "goal_bearing": sectors[:, 1],
                "distance": distance, "free_space": sectors[:, 2]}

    def features(self, o: Tensor, g: Tensor, ring: Tensor | None = None) -> Tensor:
        """``(B, 3K + 1)``: path and goal sector probabilities, log-distance, log-free."""
        return readout_features(self(o, g, ring))


def readout_features(pred: dict[str, Tensor]) -> Tensor:
    """``(B, 3K + 1)`` policy input from a readout's predictions (logits → probabilities)."""
    return torch.cat([pred["path_bearing"].softmax(-1), pred["goal_bearing"].softmax(-1),
                      pred["distance"][:, None], pred["free_space"]], dim=1)

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

    def forward(self, o: Tensor, g: Tensor) -> dict[str, Tensor]:
        """Logits ``(B, K)`` of both bearings, log-distance ``(B,)``, log-free ``(B, K)``."""
        h = self.pair(torch.cat([o, g], dim=1))
        return {"path_bearing": self.path(h), "goal_bearing": self.goal(h),
                "distance": self.distance(h).squeeze(-1), "free_space": self.free(o)}

    def features(self, o: Tensor, g: Tensor) -> Tensor:
        """``(B, 3K + 1)``: path and goal sector probabilities, log-distance, log-free."""
        pred = self(o, g)
        return torch.cat([pred["path_bearing"].softmax(-1), pred["goal_bearing"].softmax(-1),
                          pred["distance"][:, None], pred["free_space"]], dim=1)

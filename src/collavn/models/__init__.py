"""Agent models: encoders → map builder → communication → GRU core → actor / critic.

The models depend only on the observation contract of the envs (see
:mod:`collavn.models.policy`), never on the simulator.
"""

from collavn.models.communication import (
    CommCounts,
    CommProjections,
    Message,
    communication_counts,
    match_and_select,
)
from collavn.models.config import CommConfig, MapConfig, MatchConfig, ModelConfig, ReadoutConfig
from collavn.models.encoders import (
    ResNet18Encoder,
    SmallCNNEncoder,
    load_imagenet_weights,
    make_encoder,
)
from collavn.models.mapping import MapBuilder, MapEncoder, map_loss
from collavn.models.matching import GoalMatcher
from collavn.models.policy import ActorCritic, ActOutput, EvaluateOutput, PolicyStep
from collavn.models.readout import PerceptionReadout
from collavn.models.state import AgentState

__all__ = [
    "ActOutput", "ActorCritic", "AgentState", "CommConfig", "CommCounts", "CommProjections",
    "EvaluateOutput", "GoalMatcher", "MapBuilder", "MapConfig", "MapEncoder", "MatchConfig",
    "Message", "ModelConfig", "PerceptionReadout", "PolicyStep", "ReadoutConfig",
    "ResNet18Encoder", "SmallCNNEncoder",
    "communication_counts", "load_imagenet_weights", "make_encoder", "map_loss",
    "match_and_select",
]

"""Configuration of the agent model: frozen dataclasses with the `paper` and `cpu` presets.

`ModelConfig.paper()` follows Sec. 4 of the paper (ResNet18 → 1024-d, a 384×384 map at
10 cm, 256-d queries/keys, 2048-d values); `ModelConfig.cpu()` is sized for training on
a laptop CPU (small CNN, 32×128 panoramas, a 96×96 map at 20 cm).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Literal

import tyro

from collavn.configs import added_later

EncoderKind = Literal["resnet18", "small"]
CommVariant = Literal["none", "handshake", "memory"]


@dataclass(frozen=True)
class MapConfig:
    """Map building module F_map and the map encoder.

    Attributes:
        size: Cells per side of the episode map S_t (paper 384 = 38.4 m at 10 cm).
        resolution: Metres per map cell (paper 0.10).
        local_size: Cells per side of the local patch predicted from one panorama,
            agent at its centre, heading up; it covers ``local_size · resolution``
            metres, which must equal the extent of the env's ``gt_map``.
        feature_channels: Visual-feature channels of the coarse feature grid (paper 256).
        feature_size: Cells per side of the feature grid over the same extent as the map
            (paper 13 → 2.95 m cells, the paper's "3 m grid").
        encoder: Trunk of the local-patch predictor (its own weights, not shared).
        hidden: Width of the predictor's bottleneck vector.
        use_depth: Feed the depth panorama to the predictor as a 4th channel.
        max_depth: Depth (metres) that maps to 1.0 when ``use_depth``.
        agent_radius: Radius in metres of the disk drawn in the location channels.
        encoder_size: Cells per side of the egocentric window the map encoder sees;
            the window covers the whole map extent, rotated so the heading is up.
        embed_dim: Size of the map vector given to the policy.
        encoder_channels: Channels of the map encoder's three stride-2 convolutions over
            the egocentric window. The policy loss trains them, so every PPO epoch runs
            them forward and backward over every stored step.
        detach: Stop policy gradients at the local-map predictor (the paper trains the
            occupancy part of F_map only with its supervised loss). The visual-feature
            projection after it always learns from the policy loss.
    """

    size: int = 384
    resolution: float = 0.10
    local_size: int = 64
    feature_channels: int = 256
    feature_size: int = 13
    encoder: EncoderKind = "small"
    hidden: int = 512
    use_depth: bool = False
    max_depth: float = 10.0
    agent_radius: float = 0.2
    encoder_size: int = 64
    embed_dim: int = 256
    detach: bool = True
    encoder_channels: tuple[int, int, int] = (32, 64, 64)

    def __post_init__(self) -> None:
        if len(self.encoder_channels) != 3 or min(self.encoder_channels) < 1:
            raise ValueError("encoder_channels must be three positive channel counts, got "
                             f"{self.encoder_channels}")
        if self.local_size % 8 or self.encoder_size % 8:
            raise ValueError("local_size and encoder_size must be multiples of 8")
        if self.size < self.local_size or self.resolution <= 0:
            raise ValueError("map size must be >= local_size and resolution > 0")


@dataclass(frozen=True)
class CommConfig:
    """Memory-augmented handshake communication (request / match / select / store).

    Attributes:
        variant: ``none`` (no messages, IPPO), ``handshake`` (current step only, the
            paper's "w/o mem") or ``memory`` (the paper's method).
        query_dim: Size of queries μ (paper 256).
        key_dim: Size of keys κ (paper 256).
        value_dim: Size of values υ and of the message ω (paper 2048).
        memory_slots: Entries kept per agent for ``memory``: the whole episode by default
            (T = 80); a smaller number gives a FIFO of fixed capacity.
        store_interval: Store one (κ, υ) every this many steps (1 = every step).
        threshold: Selection threshold η; ``None`` means 1/N with N the active agents
            of the environment (½ for a lone agent), else a fixed value in [0, 1).
        temperature: Width of the sigmoid σ((s − η)/temperature) whose gradient the
            hard gate passes back (straight-through). The gate itself is the same hard
            indicator [s > η] in ``train()`` and ``eval()`` mode: the same ω in both.
        bytes_per_float: Wire size of one transmitted number (float32 = 4).
        critic_gradient: The critic's value loss trains the communication through the
            ω it reads (the default). ``False`` gives the critic ω detached: only the
            policy's loss shapes what is sent and when the gates open.
        listen: Teammates' entries take part in the match (the method). ``False``
            (``--model.comm.no-listen``) cuts every link between two agents, in
            training and in evaluation: each agent keeps the whole memory machinery but
            matches only its own entries, and nothing is sent. An ablation that trains
            ``ours`` without messages, to tell what its own memory gives from what its
            teammates' messages give (``collavn evaluate --mute`` cuts the links of a
            policy trained with them).
        critic_hears: The critic reads the ω the actor reads (the default). ``False``
            (``--model.comm.no-critic-hears``): the critic reads the ω the agent would
            form from its own memory alone (as with ``listen=False``), while the actor
            still hears its teammates — an ablation that tells whether teammates'
            messages help learning through the value estimates.
        actor_hears: The actor reads teammates' entries (the default). ``False``
            (``--model.comm.no-actor-hears``): the actor reads the ω of its own memory
            alone, while the critic hears its teammates — training-time information
            only, so the policy acts as a deaf one and is evaluated so; the other arm of
            the ``critic_hears`` ablation.
    """

    variant: Annotated[CommVariant, tyro.conf.Suppress] = "memory"
    query_dim: int = 256
    key_dim: int = 256
    value_dim: int = 2048
    memory_slots: int = 80
    store_interval: int = 1
    threshold: float | None = None
    temperature: float = 0.05
    bytes_per_float: int = 4
    critic_gradient: bool = True
    listen: bool = added_later(True)
    critic_hears: bool = added_later(True)
    actor_hears: bool = added_later(True)

    def __post_init__(self) -> None:
        if self.memory_slots < 1 or self.store_interval < 1:
            raise ValueError("memory_slots and store_interval must be >= 1")
        if self.threshold is not None and not 0.0 <= self.threshold < 1.0:
            raise ValueError(f"threshold must be in [0, 1) (scores are), got {self.threshold}")
        if self.temperature <= 0:
            raise ValueError(f"temperature must be > 0, got {self.temperature}")


@dataclass(frozen=True)
class MatchConfig:
    """Goal matching (:class:`collavn.models.matching.GoalMatcher`; not in the paper).

    Attributes:
        enabled: Add the goal-matching vector to the goal embedding.
        channels: Feature channels compared (the last 3 are the pooled RGB).
        scales: Sizes of the goal template relative to the goal image (1 = same angular
            size; smaller = its content seen from farther away).
        output_size: Size of the match vector.
    """

    enabled: bool = False
    channels: int = 32
    scales: tuple[float, ...] = (1.0, 0.5, 0.25)
    output_size: int = 64

    def __post_init__(self) -> None:
        if self.channels <= 3 or not self.scales or min(self.scales) <= 0:
            raise ValueError("goal matching needs channels > 3 (3 are the pooled RGB) and "
                             f"positive scales, got channels={self.channels}, "
                             f"scales={self.scales}")


@dataclass(frozen=True)
class ReadoutConfig:
    """Perception readout (:class:`collavn.models.readout.PerceptionReadout`; not in the paper).

    The heads that ``collavn pretrain`` trains on simulator labels stay in the model and
    their predictions join the goal embedding: where the shortest path and the goal lie
    (a distribution over ``bins`` panorama sectors each), the geodesic distance and the
    free space per sector. A policy then reads "turn towards sector k" nearly linearly
    instead of rediscovering it from two embeddings.

    Attributes:
        enabled: Append the readout to the goal embedding.
        bins: Azimuth sectors (must divide the panorama width; pretraining's
            ``perception.bins`` must agree).
        hidden: Width of the heads' hidden layer (pretraining's ``perception.hidden``).
        ring: Predict bearings and free space per azimuth with one circular convolution
            over the goal matcher's feature columns
            (:class:`~collavn.models.readout.RingReadout`: rotation-equivariant) instead
            of MLPs on the pooled embeddings. Needs goal matching.
    """

    enabled: bool = False
    bins: int = 16
    hidden: int = 256
    ring: bool = False

    def __post_init__(self) -> None:
        if self.bins < 1 or self.hidden < 1:
            raise ValueError(f"readout bins and hidden must be ≥ 1, got bins={self.bins}, "
                             f"hidden={self.hidden}")

    @property
    def size(self) -> int:
        """Width of the readout vector: two bearing distributions, distance, free space."""
        return 3 * self.bins + 1 if self.enabled else 0


@dataclass(frozen=True)
class ModelConfig:
    """The whole agent: encoders → map → communication → GRU core → actor / critic.

    Attributes:
        encoder: Visual trunk of the panorama and goal encoders.
        embed_dim: Size of the panorama and goal embeddings (paper 1024).
        panorama_shape: ``(C, H, W)`` of the panorama (cylindrical, heading at the
            centre column).
        goal_shape: ``(C, H, W)`` of the goal image.
        weights_path: Local file with torchvision ImageNet ResNet18 weights to load
            into the trunks; ``None`` keeps the random initialisation.
        hidden_size: Hidden size of the actor GRU.
        critic_hidden_size: Hidden size of the critic GRU.
        critic_full_input: The critic also sees the map vector and the goal embedding
            (the paper's V sees only (O, ω)).
        odometry_input: Append the last step's ``pose_delta`` to the map vector, so the
            policy sees directly whether its last action moved it (a blocked robot
            does not move; not in the paper).
        free_space_input: Directions of the ``free_space`` sensor appended to the map
            vector (0 = off; a run sets ``EnvConfig.free_space`` to match): how far the
            body can drive straight each way, read off the depth panorama — the
            explorer's sense, so a policy can stop pushing into walls (not in the paper).
        explore_prior: The actor's means are the ``explore_action`` sensor's move (the
            goal-blind explorer's, :class:`~collavn.envs.free_space.ExploreRule`) plus
            what the actor head adds, and that move joins the map vector (a run sets
            ``EnvConfig.explore_action``). The head starts near zero, so an untrained
            policy explores like the explorer; what it learns is where and how to leave
            the search for the goal — the seeker's homing — instead of re-deriving the
            search from depth and odometry (not in the paper; a residual policy).
        frame_depth: The panorama encoder (frame perception) also reads the depth
            panorama, as a 4th channel scaled like the map's (``map.max_depth`` → 1).
            Where the goal is 1–2 m away, which way it lies is a question of geometry
            (how far the goal view's surfaces are from where the goal camera stood, and
            from here), which 32-pixel-high RGB answers poorly; the depth sensor is
            there anyway (the map is supervised by it). Not in the paper; the goal image
            stays RGB, as the task gives it. Measured (docs/learning-log.md,
            2026-12-06): held-out path direction 1–2 m from the goal 0.445 → 0.485, but
            ``il`` on it no better (−0.038 and −0.010 easy SR over two seeds), so it is
            off in ``cpu``.
        goal_belief: Sectors of an auxiliary head on the actor's GRU state that says
            where the goal is: its egocentric straight-line bearing (one of
            ``goal_belief`` sectors, the first centred straight ahead) and its log
            distance. ``il`` trains it on privileged labels of the states it visits
            (``--imitation.belief-coef``); no action reads it, and PPO neither reads
            nor trains it. It asks the recurrent state to carry the goal's position
            from step to step on the policy's own trajectories, where the frame
            perception alone is right least often (1–2 m from the goal). 0 = no head,
            1 is refused (not in the paper). Measured (docs/learning-log.md,
            2026-12-06): on ``il``'s own val trajectories the head's bearing is right
            (±1 of 16 sectors) on 0.39 of steps 1–2 m from the goal where the readout is
            on 0.27, and agents end nearer their goals, but ``il``'s SR did not rise
            (−0.010 and −0.015 easy over two seeds), so it is off in ``cpu``.
        log_std_init: Initial log standard deviation of the Gaussian policy.
        action_modes: Components of the action distribution: 1 = one diagonal Gaussian
            (the paper's); K > 1 = a mixture of K Gaussians with learned weights (shared
            σ), whose deterministic action is the mean of its most probable component.
            Where the expert goes left or right for reasons the policy cannot see (an
            obstacle ahead, the goal out of sight), one Gaussian's mean averages the two
            into "straight on" — into the wall; a mixture keeps both and picks one.
        per_agent_params: One set of weights per agent slot instead of shared weights.
        max_agents: Number of agent slots when ``per_agent_params`` (ignored otherwise).
        map: The map module.
        comm: The communication module.
        goal_match: Goal matching (off in the paper's model, on in ``cpu``).
        readout: The pretraining heads' predictions as inputs (off in the paper's
            model, on in ``cpu``).
    """

    encoder: EncoderKind = "resnet18"
    embed_dim: int = 1024
    panorama_shape: Annotated[tuple[int, int, int], tyro.conf.Suppress] = (3, 128, 512)
    goal_shape: Annotated[tuple[int, int, int], tyro.conf.Suppress] = (3, 128, 128)
    weights_path: str | None = None
    hidden_size: int = 512
    critic_hidden_size: int = 512
    critic_full_input: bool = False
    odometry_input: bool = False
    free_space_input: int = 0
    explore_prior: bool = False
    frame_depth: bool = False
    goal_belief: int = 0
    log_std_init: float = -0.5
    action_modes: int = 1
    per_agent_params: bool = False
    max_agents: int = 4
    map: MapConfig = field(default_factory=MapConfig)
    comm: CommConfig = field(default_factory=CommConfig)
    goal_match: MatchConfig = field(default_factory=MatchConfig)
    readout: ReadoutConfig = field(default_factory=ReadoutConfig)

    @property
    def reads_depth(self) -> bool:
        """The model reads the depth panorama (the map's predictor or the frame perception)."""
        return self.map.use_depth or self.frame_depth

    def __post_init__(self) -> None:
        if self.free_space_input < 0:
            raise ValueError(f"free_space_input must be ≥ 0, got {self.free_space_input}")
        if self.goal_belief < 0 or self.goal_belief == 1:
            raise ValueError(f"goal_belief must be 0 (no head) or ≥ 2 sectors, got "
                             f"{self.goal_belief}")
        if self.action_modes < 1:
            raise ValueError(f"action_modes must be ≥ 1, got {self.action_modes}")
        if self.readout.enabled and self.readout.ring and not self.goal_match.enabled:
            raise ValueError("readout.ring reads the goal matcher's feature columns: "
                             "enable goal_match too")

    @classmethod
    def paper(cls, **overrides: object) -> ModelConfig:
        """The paper's sizes (ResNet18, 3×128×512 panoramas, 384×384 map)."""
        return cls(**overrides)  # type: ignore[arg-type]

    @classmethod
    def cpu(cls, **overrides: object) -> ModelConfig:
        """Laptop-CPU sizes (small CNN, 3×32×128 panoramas, 96×96 map at 20 cm).

        Also on: goal matching, the perception readout, odometry input, 16 free-space
        directions, a critic that sees the goal and the map.
        """
        base: dict[str, object] = dict(
            encoder="small", embed_dim=256, panorama_shape=(3, 32, 128),
            goal_shape=(3, 32, 32), hidden_size=256, critic_hidden_size=128,
            map=MapConfig(size=96, resolution=0.2, local_size=32, feature_channels=32,
                          feature_size=6, hidden=256, encoder_size=32, embed_dim=128,
                          encoder_channels=(16, 32, 32)),
            comm=CommConfig(query_dim=64, key_dim=64, value_dim=256),
            goal_match=MatchConfig(enabled=True), critic_full_input=True,
            odometry_input=True, readout=ReadoutConfig(enabled=True), free_space_input=16,
        )
        base.update(overrides)
        return cls(**base)  # type: ignore[arg-type]

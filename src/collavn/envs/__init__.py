"""Environment front doors: a PettingZoo ``ParallelEnv`` and a batched vector env."""

from collavn.envs.config import EnvConfig, EpisodeSource
from collavn.envs.parallel import CollaVNParallelEnv, make_parallel_env
from collavn.envs.vector import AUTORESET_MODE, VectorEnv

__all__ = ["AUTORESET_MODE", "CollaVNParallelEnv", "EnvConfig", "EpisodeSource", "VectorEnv",
           "make_parallel_env"]

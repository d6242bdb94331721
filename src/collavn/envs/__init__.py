"""Environment front doors: a PettingZoo ``ParallelEnv`` and batched vector envs.

:class:`SplitVectorEnv` is a vector env in parts, stepped on a worker thread (training).
"""

from collavn.envs.config import EnvConfig, EpisodeSource
from collavn.envs.parallel import CollaVNParallelEnv, make_parallel_env
from collavn.envs.split import SplitVectorEnv
from collavn.envs.vector import AUTORESET_MODE, VectorEnv

__all__ = ["AUTORESET_MODE", "CollaVNParallelEnv", "EnvConfig", "EpisodeSource",
           "SplitVectorEnv", "VectorEnv", "make_parallel_env"]

"""Training: rollout storage + GAE, decentralized PPO, imitation, map FIFO, distributed runs.

The loop lives in :func:`collavn.training.trainer.train`; ``collavn train`` is
:class:`collavn.training.command.Train`.
"""

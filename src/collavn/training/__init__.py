"""Training: rollout storage + GAE, decentralized PPO, imitation, map FIFO, distributed runs.

The loop is :func:`collavn.training.trainer.train` (collect → GAE → PPO epochs → log →
checkpoint); ``collavn train`` (:mod:`collavn.cli.train`) sets every field of its config tree::

    collavn train --method ours --task commongoal --agents 2 --preset cpu --out runs/ours
    collavn train --method il --preset cpu --time-budget-minutes 50 --out runs/il
    collavn train --method ours --preset cpu --out runs/ours --resume
    torchrun --nproc-per-node 2 -m collavn.cli train --method no-com --preset cpu --out runs/d

Methods: ``ours`` (memory communication), ``no-mem`` (handshake), ``no-com`` (IPPO) —
all decentralized PPO with per-agent critics — and ``il`` (one agent clones a
privileged expert, the oracle or the seeker; copies of it act at test time). ``random`` lives in
:mod:`collavn.policies`. Presets: ``paper`` keeps the paper's values;
``cpu`` departs from them as :func:`collavn.training.presets.preset_deviations`
computes, each with its reason.
"""

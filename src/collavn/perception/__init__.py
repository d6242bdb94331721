"""Supervised pretraining of the frame perception from simulator labels.

:mod:`.labels` (what the simulator knows: path and goal bearings, geodesic distance,
free space), :mod:`.frames` (rendered, labelled frame sets and augmented batches),
:mod:`.heads` (pretraining heads, losses, held-out accuracies), :mod:`.pretrain` (the
loop behind ``collavn pretrain``) and :mod:`.encoder` (the ``encoder.pt`` file and
installing it, frozen, into a model for ``collavn train --encoder``).
"""

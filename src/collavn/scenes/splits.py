"""Train / val / test splits of procedural apartments, by seed.

The paper used 25 / 5 / 5 Gibson scenes; we keep the counts and draw each split's
apartments from its own seed range, so the splits never share a scene:

========  ==================  =========================
split     seeds               default (``sizes=(25, 5, 5)``)
========  ==================  =========================
train     ``0, 1, 2, ...``    0–24
val       ``1000, 1001, ...`` 1000–1004
test      ``2000, 2001, ...`` 2000–2004
========  ==================  =========================

Each range holds up to :data:`SPLIT_STRIDE` seeds, so larger splits stay disjoint.
"""

from __future__ import annotations

from typing import Literal, get_args

from collavn.errors import SceneError

#: A split's name.
Split = Literal["train", "val", "test"]
#: The splits, in the order of ``sizes``.
SPLITS: tuple[str, ...] = get_args(Split)
#: First seed of each split's range; ranges are this far apart.
SPLIT_STRIDE = 1000


def split_seeds(split: str, sizes: tuple[int, int, int] = (25, 5, 5)) -> list[int]:
    """Seeds of the apartments in ``split``.

    Args:
        split: ``"train"``, ``"val"`` or ``"test"``.
        sizes: Number of scenes in train, val and test.

    Raises:
        SceneError: for an unknown split or a size outside ``0..SPLIT_STRIDE``.
    """
    if split not in SPLITS:
        raise SceneError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    k = SPLITS.index(split)
    if not 0 <= sizes[k] <= SPLIT_STRIDE:
        raise SceneError(f"split {split!r}: size must be in 0..{SPLIT_STRIDE}, "
                         f"got {sizes[k]}")
    return list(range(k * SPLIT_STRIDE, k * SPLIT_STRIDE + sizes[k]))


def scene_specs(split: str, sizes: tuple[int, int, int] = (25, 5, 5)) -> list[str]:
    """Scene specs (``procedural:SEED``) of ``split``, for :func:`collavn.scenes.load_scene`."""
    return [f"procedural:{seed}" for seed in split_seeds(split, sizes)]

"""Pictures of what the agents see: panoramas beside goal images."""

from __future__ import annotations

import numpy as np

#: Distinct colours per agent index (RGB uint8), shared by maps and frames.
AGENT_COLOURS = np.array([[31, 119, 180], [214, 39, 40], [44, 160, 44], [148, 103, 189],
                          [255, 127, 14], [23, 190, 207], [227, 119, 194], [140, 86, 75]],
                         dtype=np.uint8)


def views_strip(panoramas: np.ndarray, goals: np.ndarray, gap: int = 4) -> np.ndarray:
    """One picture of N agents' views, a row per agent: coloured tab, panorama, goal.

    Args:
        panoramas: ``(N, 3, H, W)`` uint8.
        goals: ``(N, 3, G, G)`` uint8.
        gap: White pixels between rows and images.

    Returns:
        ``(N·(max(H, G) + gap) + gap, W + G + 3·gap + tab, 3)`` uint8.
    """
    n, _, h, w = panoramas.shape
    g = goals.shape[-1]
    row_h, tab = max(h, g), 6
    out = np.full((n * (row_h + gap) + gap, tab + w + g + 3 * gap, 3), 255, np.uint8)
    for i in range(n):
        top = gap + i * (row_h + gap)
        out[top:top + row_h, 0:tab] = AGENT_COLOURS[i % len(AGENT_COLOURS)]
        out[top:top + h, tab + gap:tab + gap + w] = panoramas[i].transpose(1, 2, 0)
        out[top:top + g, tab + 2 * gap + w:tab + 2 * gap + w + g] = goals[i].transpose(1, 2, 0)
    return out

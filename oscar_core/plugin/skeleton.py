"""The skeleton spec: which links become points, how they are joined, their colours."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Skeleton", "DEFAULT_PALETTE", "collapse_tree_edges"]

# Distinct, saturated RGB colours that stay apart after H.264 chroma
# subsampling; assigned to limb groups in order unless a plugin names colours.
DEFAULT_PALETTE: tuple[tuple[int, int, int], ...] = (
    (255, 170, 0),  # orange
    (0, 170, 255),  # sky blue
    (255, 60, 200),  # magenta
    (120, 255, 60),  # lime
    (255, 255, 80),  # yellow
    (140, 100, 255),  # violet
    (0, 255, 200),  # aqua
    (255, 110, 90),  # coral
)


def collapse_tree_edges(links: Sequence[str], parent_of: Mapping[str, str]) -> tuple[tuple[str, str], ...]:
    """Edges of the kinematic tree collapsed onto the chosen ``links``.

    Each chosen link is joined to its nearest chosen ancestor; a chosen link
    with no chosen ancestor starts a new tree. Returns (parent, child) pairs in
    the order of ``links``.
    """
    chosen = set(links)
    edges = []
    for link in links:
        cur = link
        while cur in parent_of:
            cur = parent_of[cur]
            if cur in chosen:
                edges.append((cur, link))
                break
    return tuple(edges)


@dataclass(frozen=True)
class Skeleton:
    """What an embodiment draws.

    links: K names of the links (or keypoints) that become points, in order.
    points: canonical point o_k per link in that link's frame (metres);
        links not listed use their origin (0, 0, 0).
    edges: (parent, child) pairs; None derives them from the kinematic tree.
    groups: limb group name → links; each link in at most one group, links
        in none form the group "body". Colours are per group.
    colors: group name → RGB 0–255; groups without an entry take
        :data:`DEFAULT_PALETTE` colours in group order.
    """

    links: tuple[str, ...]
    points: Mapping[str, tuple[float, float, float]] = field(default_factory=dict)
    edges: tuple[tuple[str, str], ...] | None = None
    groups: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    colors: Mapping[str, tuple[int, int, int]] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "links", tuple(self.links))
        if self.edges is not None:
            object.__setattr__(self, "edges", tuple(tuple(e) for e in self.edges))
        object.__setattr__(self, "groups", {g: tuple(ls) for g, ls in self.groups.items()})

    def problems(self, known_links: Sequence[str] | None = None) -> list[str]:
        """Everything wrong with this spec, as sentences (empty when valid)."""
        out = []
        if not self.links:
            out.append("skeleton.links: expected at least one link, found none")
        dup = sorted({l for l in self.links if self.links.count(l) > 1})
        if dup:
            out.append(f"skeleton.links: expected unique names, found duplicates {dup}")
        chosen = set(self.links)
        if known_links is not None:
            unknown = [l for l in self.links if l not in set(known_links)]
            if unknown:
                out.append(f"skeleton.links: expected links of the kinematic tree, found unknown {unknown}")
        for l, p in self.points.items():
            if l not in chosen:
                out.append(f"skeleton.points[{l!r}]: expected a link in skeleton.links")
            if np.shape(p) != (3,) or not np.all(np.isfinite(np.asarray(p, dtype=float))):
                out.append(f"skeleton.points[{l!r}]: expected 3 finite numbers (metres), found {p!r}")
        for e in self.edges or ():
            if len(e) != 2 or e[0] not in chosen or e[1] not in chosen or e[0] == e[1]:
                out.append(f"skeleton.edges: expected pairs of two different skeleton links, found {e!r}")
        seen: dict[str, str] = {}
        for g, ls in self.groups.items():
            for l in ls:
                if l not in chosen:
                    out.append(f"skeleton.groups[{g!r}]: expected skeleton links, found {l!r}")
                elif l in seen:
                    out.append(f"skeleton.groups: link {l!r} is in both {seen[l]!r} and {g!r}")
                seen[l] = g
        for g, c in self.colors.items():
            if len(c) != 3 or not all(isinstance(v, (int, np.integer)) and 0 <= v <= 255 for v in c):
                out.append(f"skeleton.colors[{g!r}]: expected 3 integers 0-255, found {c!r}")
        return out

    def group_of(self) -> dict[str, str]:
        """link → group name (``"body"`` for links in no group)."""
        out = {l: "body" for l in self.links}
        for g, ls in self.groups.items():
            for l in ls:
                out[l] = g
        return out

    def group_colors(self) -> dict[str, tuple[int, int, int]]:
        """group → RGB for every group that has a link."""
        names = list(self.groups) + (["body"] if "body" not in self.groups else [])
        used = set(self.group_of().values())
        out, k = {}, 0
        for g in names:
            if g not in used and g not in self.colors:
                continue
            if g in self.colors:
                out[g] = tuple(int(v) for v in self.colors[g])
            else:
                out[g] = DEFAULT_PALETTE[k % len(DEFAULT_PALETTE)]
                k += 1
        return out

    def point_offsets(self) -> np.ndarray:
        """(K, 3) canonical points o_k in their link frames, metres."""
        return np.array([self.points.get(l, (0.0, 0.0, 0.0)) for l in self.links], dtype=float)

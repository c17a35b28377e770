"""The cheapest pairing of a few chain ends, each end left unpaired at a cost.

Merging pairs the ends that meet at a junction (:func:`.merging._best_matchings`) and the
free ends where a cable turns out of sight (:func:`.turn_joins.turn_joins`) this way:
together, so that one early bad join cannot force later ones.
"""

from __future__ import annotations


class Components:
    """Union-find over ``count`` items (pieces, ends): which are linked, directly or
    through others, so that a join never closes a chain on itself."""

    def __init__(self, count: int):
        self.parent = list(range(count))

    def find(self, item: int) -> int:
        while self.parent[item] != item:
            self.parent[item] = self.parent[self.parent[item]]
            item = self.parent[item]
        return item

    def union(self, a: int, b: int) -> None:
        self.parent[self.find(a)] = self.find(b)


def cheapest_pairing(
    members: list[int], costs: dict[tuple[int, int], float], unpaired_penalty: float
) -> list[tuple[int, int, float]]:
    """The pairs of ``members`` of least total cost, each end left unpaired costing
    ``unpaired_penalty``; ``costs[a, b]`` (``a`` before ``b`` in ``members``) holds every
    pair allowed. Exact, by trying every pairing (exponential: for a dozen ends or so).
    """
    memo: dict[tuple[int, ...], tuple[float, tuple]] = {}

    def solve(remaining: tuple[int, ...]) -> tuple[float, tuple]:
        if not remaining:
            return 0.0, ()
        if remaining in memo:
            return memo[remaining]
        first, rest = remaining[0], remaining[1:]
        best_cost, rest_pairs = solve(rest)
        best = (best_cost + unpaired_penalty, rest_pairs)
        for index, other in enumerate(rest):
            cost = costs.get((first, other))
            if cost is None:
                continue
            sub_cost, sub_pairs = solve(rest[:index] + rest[index + 1 :])
            if cost + sub_cost < best[0]:
                best = (cost + sub_cost, ((first, other, cost), *sub_pairs))
        memo[remaining] = best
        return best

    return list(solve(tuple(members))[1])

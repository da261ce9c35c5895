"""Oracle for the smoother's discrete pass: every path through small candidate sets enumerated,
its log probability the sum of its emissions and transitions, marginals and the best path
read off the enumeration (exponential in frames: for a handful of frames only)."""

from __future__ import annotations

import itertools

import numpy as np


def enumerate_paths(emissions: list[np.ndarray], transitions: list[np.ndarray],
                    prior0: np.ndarray | None = None):
    """(posterior marginals per frame, the most probable path, its log probability, the
    second best's) from log emissions (K_t,) and log transitions (K_t-1, K_t)."""
    sizes = [len(e) for e in emissions]
    prior0 = np.zeros(sizes[0]) if prior0 is None else prior0
    paths, logps = [], []
    for path in itertools.product(*[range(k) for k in sizes]):
        lp = prior0[path[0]] + sum(emissions[t][path[t]] for t in range(len(path)))
        lp += sum(transitions[t - 1][path[t - 1], path[t]] for t in range(1, len(path)))
        paths.append(path)
        logps.append(lp)
    logps = np.array(logps)
    w = np.exp(logps - logps.max())
    w /= w.sum()
    marg = [np.zeros(k) for k in sizes]
    for path, p in zip(paths, w):
        for t, k in enumerate(path):
            marg[t][k] += p
    order = np.argsort(-logps)
    second = logps[order[1]] if len(order) > 1 else -np.inf
    return marg, paths[order[0]], logps[order[0]], second

"""Tucker (HOSVD) latent skills, the Matrix (SVD) baseline and Algorithm 5 target learning (§5.2.2-5.2.3).

Conventions (tensorly's): the source weights form a tensor ``W`` of shape ``(D, A, P)``; HOSVD gives the
core ``G`` (r1, r2, r3) and factors ``U1`` (D, r1), ``U2`` (A, r2), ``U3`` (P, r3) with orthonormal
columns, ``W ≈ G ×1 U1 ×2 U2 ×3 U3`` (Eq 5.10; the thesis writes the factors transposed). The latent
skills are ``L = G ×1 U1 ×2 U2`` (D, A, r3) and a task is ``W = L ×3 s`` for a task vector ``s`` (r3,).

Algorithm 5 (:func:`alternate`): initialise ``s`` as the row of ``U3`` of one random source task, then
alternate CMA-ES phases on ``s`` (``L`` fixed) and on ``L`` (``s`` fixed). In the tensor strategy the
``L``-phase searches the factors ``(G, U1, U2)`` (sharing across actuators is kept); in the Matrix
strategy ``L`` is the ``DA × K`` basis of the SVD of the ``DA × P`` unfolding and is searched whole.

>>> rng = np.random.default_rng(0)
>>> W = rng.normal(size=(6, 2, 5))
>>> t = hosvd(W, (6, 2, 5))
>>> bool(np.allclose(t.to_tensor(), W))
True
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from thesis_repro.arm.cma import CMAResult, cma_lockstep, default_popsize
from thesis_repro.core.validation import check_choice, check_nonneg

STRATEGIES: tuple[str, ...] = ("tensor", "matrix")


def _check_tensor(W: np.ndarray) -> np.ndarray:
    W = np.asarray(W, dtype=float)
    if W.ndim != 3:
        raise ValueError(f"expected a 3-way weight tensor (D, A, P), got shape {W.shape}")
    return W


def _check_ranks(ranks: Sequence[int], shape: tuple[int, ...]) -> tuple[int, ...]:
    ranks = tuple(int(r) for r in ranks)
    if len(ranks) != len(shape) or any(not 1 <= r <= s for r, s in zip(ranks, shape, strict=True)):
        raise ValueError(f"ranks must satisfy 1 <= r_i <= {shape}, got {ranks}")
    return ranks


@dataclass
class Tucker:
    """A Tucker decomposition ``X = G ×1 U1 ×2 U2 ×3 U3`` (factors with shapes (D_i, r_i))."""

    core: np.ndarray
    factors: list[np.ndarray]

    def to_tensor(self) -> np.ndarray:
        """Multiply out Eq 5.10."""
        from tensorly.tenalg import multi_mode_dot  # local: tensorly is slow to import (start-up time)

        return np.asarray(multi_mode_dot(self.core, self.factors))

    def latent(self) -> np.ndarray:
        """Task-agnostic latent skills ``L = G ×1 U1 ×2 U2``, shape (D, A, r3)."""
        from tensorly.tenalg import multi_mode_dot  # local: tensorly is slow to import (start-up time)

        return np.asarray(multi_mode_dot(self.core, self.factors[:2], modes=[0, 1]))


def hosvd(X: np.ndarray, ranks: Sequence[int]) -> Tucker:
    """Algorithm 4: ``U_i`` = leading ``r_i`` left singular vectors of the mode-i unfolding, then Eq 5.11.

    >>> t = hosvd(np.arange(24.0).reshape(3, 2, 4), (2, 2, 2))
    >>> t.core.shape, [u.shape for u in t.factors]
    ((2, 2, 2), [(3, 2), (2, 2), (4, 2)])
    """
    from tensorly import unfold  # local: tensorly is slow to import (start-up time)
    from tensorly.tenalg import multi_mode_dot

    X = np.asarray(X, dtype=float)
    ranks = _check_ranks(ranks, X.shape)
    factors = []
    for mode, r in enumerate(ranks):
        U, _, _ = np.linalg.svd(np.asarray(unfold(X, mode)), full_matrices=False)
        factors.append(U[:, :r])
    core = np.asarray(multi_mode_dot(X, factors, transpose=True))
    return Tucker(core=core, factors=factors)


def matrix_svd(W: np.ndarray, rank: int) -> tuple[np.ndarray, np.ndarray]:
    """Matrix baseline: SVD of the ``DA × P`` matrix of stacked policies.

    Returns the basis ``L`` (D, A, K) (= ``U_K S_K`` reshaped) and the task coefficients (P, K) (= ``V_K``)
    so that ``compose(L, coeffs[p]) ≈ W[:, :, p]``.

    >>> L, S = matrix_svd(np.ones((4, 2, 3)), 1)
    >>> L.shape, S.shape
    ((4, 2, 1), (3, 1))
    """
    W = _check_tensor(W)
    D, A, P = W.shape
    (K,) = _check_ranks([rank], (min(D * A, P),))
    U, S, Vt = np.linalg.svd(W.reshape(D * A, P), full_matrices=False)
    return (U[:, :K] * S[:K]).reshape(D, A, K), Vt[:K].T.copy()


def compose(L: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``W = L ×3 s``: latent skills (D, A, K) and task vectors (..., K) -> policies (..., D, A)."""
    return np.einsum("dak,...k->...da", L, s)


@dataclass
class Subspace:
    """A transferred subspace: how to build ``L`` from a flat parameter vector, and its initial point.

    ``kind="tensor"``: parameters are (G, U1, U2) with ``L = G ×1 U1 ×2 U2``; ``kind="matrix"``: the flat
    ``L`` itself. ``s0`` (P, K) are the source tasks' coordinates (Algorithm 5 starts from one of them).
    """

    kind: str
    shapes: list[tuple[int, ...]]
    theta0: np.ndarray
    s0: np.ndarray

    def latent(self, theta: np.ndarray) -> np.ndarray:
        """``L`` for parameters ``theta`` (..., n_theta) -> (..., D, A, K)."""
        theta = np.asarray(theta, dtype=float)
        parts, i = [], 0
        for shp in self.shapes:
            size = int(np.prod(shp))
            parts.append(theta[..., i : i + size].reshape(*theta.shape[:-1], *shp))
            i += size
        if self.kind == "matrix":
            return parts[0]
        G, U1, U2 = parts
        return np.einsum("...ijk,...di,...aj->...dak", G, U1, U2)

    @property
    def rank(self) -> int:
        return self.s0.shape[1]


def make_subspace(W_sources: np.ndarray, kind: str, ranks: Sequence[int] | None = None) -> Subspace:
    """Factorise the source tensor (D, A, P) for transfer: ``kind`` in :data:`STRATEGIES`.

    ``ranks`` = (r1, r2, r3) for the tensor (default full rank), and only ``r3`` is used for the matrix.

    >>> sub = make_subspace(np.random.default_rng(0).normal(size=(5, 2, 4)), "tensor", (3, 2, 2))
    >>> sub.latent(sub.theta0).shape, sub.s0.shape
    ((5, 2, 2), (4, 2))
    """
    check_choice(kind, STRATEGIES, "transfer strategy")
    W = _check_tensor(W_sources)
    D, A, P = W.shape
    ranks = _check_ranks(ranks or (D, A, P), (D, A, P))
    if kind == "matrix":
        L, S = matrix_svd(W, min(ranks[2], D * A))
        return Subspace("matrix", [L.shape], L.ravel(), S)
    t = hosvd(W, ranks)
    G, U1, U2 = t.core, t.factors[0], t.factors[1]
    theta = np.concatenate([G.ravel(), U1.ravel(), U2.ravel()])
    return Subspace("tensor", [G.shape, U1.shape, U2.shape], theta, t.factors[2])


@dataclass
class AlternateResult:
    """Algorithm 5 outcome for ``n`` target tasks: final ``W`` (n, D, A), concatenated curves (n, G_total)."""

    W: np.ndarray
    s: np.ndarray
    theta: np.ndarray
    curve: np.ndarray
    success: np.ndarray
    popsize: int
    phases: list[str]

    @property
    def total_cost(self) -> np.ndarray:
        return self.popsize * self.curve.sum(axis=1)


#: ``objective(W (n, pop, D, A))`` -> ``(cost, success)`` or ``(fitness, cost, success)``, each (n, pop):
#: the optimised fitness (e.g. a shaped cost), the task cost recorded in the curves, and 0/1 success.
Objective = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


def alternate(
    objective: Objective,
    sub: Subspace,
    n: int,
    *,
    rounds: int,
    generations: int,
    sigma_s: float = 0.01,
    sigma_L: float = 0.01,
    l2: float = 0.0,
    popsize: int | None = None,
    seed: int = 0,
    init_noise: float = 0.0,
) -> AlternateResult:
    """Algorithm 5 for ``n`` target tasks at once: ``rounds`` × (CMA-ES on s, then CMA-ES on L).

    ``s`` starts at the coordinates of a random source task per target (+ ``init_noise`` Gaussian);
    ``L`` starts at the transferred subspace. Each phase runs ``generations`` CMA-ES generations; the
    fitness is the objective's fitness + ``l2 * |W|²`` (L2 on the output weights), the curves record the
    task cost. Each generation evaluates ``n × popsize`` policies in one ``objective`` call.
    """
    check_nonneg(l2, "l2")
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    rng = np.random.default_rng(seed)
    s = sub.s0[rng.integers(0, len(sub.s0), size=n)] + init_noise * rng.normal(size=(n, sub.rank))
    theta = np.tile(sub.theta0, (n, 1))
    curves, succs, phases = [], [], []
    pop = int(popsize or default_popsize(sub.theta0.size))
    for r in range(rounds):
        for phase in ("s", "L"):
            if phase == "s":
                L = sub.latent(theta)  # (n, D, A, K)

                def decode(X: np.ndarray, L: np.ndarray = L) -> np.ndarray:
                    return np.einsum("ndak,npk->npda", L, X)

                x0, sigma = s, sigma_s
            else:
                s_fixed = s

                def decode(X: np.ndarray, s_fixed: np.ndarray = s_fixed) -> np.ndarray:
                    return np.einsum("npdak,nk->npda", sub.latent(X), s_fixed)

                x0, sigma = theta, sigma_L

            def evaluate(X: np.ndarray, decode=decode) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
                W = decode(X)
                out = objective(W)
                fit, cost, success = out if len(out) == 3 else (out[0], *out)
                return fit + l2 * (W**2).sum(axis=(-2, -1)), cost, success

            res: CMAResult = cma_lockstep(
                evaluate, x0, sigma, generations, popsize=pop, seed=seed * 1000 + 2 * r + (phase == "L")
            )
            if phase == "s":
                s = res.x
            else:
                theta = res.x
            curves.append(res.curve)
            succs.append(res.success)
            phases.extend([phase] * generations)
    W = np.einsum("ndak,nk->nda", sub.latent(theta), s)
    return AlternateResult(
        W=W,
        s=s,
        theta=theta,
        curve=np.concatenate(curves, axis=1),
        success=np.concatenate(succs, axis=1),
        popsize=pop,
        phases=phases,
    )

"""The DMP-inspired RBF-PD policy network of §5.2.1 (Eq 5.5–5.8), batched over policies.

Per actuator ``i`` (A = 2: horizontal and vertical end-effector acceleration) the column ``W[:, i]`` of
``W ∈ R^{D×A}``, ``D = N + 2``, holds the RBF weights ``Θ_i = W[:N, i]`` and the PD gains
``Ψ_i = W[N:, i]``:

* Eq 5.5  ``φ_n(t) = exp(-(t - μ_n)² / (2σ_n²)) / sqrt(2π σ_n)`` (the thesis's normalisation, kept as
  printed), centres ``μ_n`` evenly spaced over the episode ``[0, horizon·dt]`` seconds, widths
  ``σ_n = width × spacing``;
* Eq 5.6  desired position ``x^d_{t,i} = Θ_i Φ(t)`` (an offset from the start position, which is the
  origin of the simulator's frame);
* Eq 5.7  desired velocity by central differences ``(x^d_{t+Δt} - x^d_{t-Δt}) / 2Δt``;
* Eq 5.8  ``a_{t,i} = Ψ_i · (x^d_{t,i} - x^o_{t,i})`` with ``x = (position, velocity)``, i.e. a PD
  controller with ``kp_i = kp_scale · W[N, i]`` and ``kd_i = kd_scale · W[N+1, i]``. The fixed scales
  make ``W`` entries O(1) (gains 1, 1 = critically damped, ω = 10 rad/s), so one CMA-ES ``σ`` suits
  every parameter.

Flat parameter vectors (dmpbbo style) are ``W.reshape(-1)`` in C order: ``flat[d * A + i] = W[d, i]``.

>>> pol = RBFPolicy(n_basis=6, horizon=50, dt=0.02)
>>> W = pol.default_params()
>>> W.shape, pol.n_params
((8, 2), 16)
>>> xd, vd = pol.desired(W)
>>> xd.shape, float(abs(xd).max())
((1, 50, 2), 0.0)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from thesis_repro.core.validation import check_nonneg, check_positive

A: int = 2  #: actuators: horizontal and vertical end-effector acceleration


@dataclass
class RBFPolicy:
    """RBF trajectory layer + PD layer (Eq 5.5–5.8); ``W`` (D, A) is the policy's own parameter matrix.

    ``n_basis`` N RBFs over ``horizon`` control steps of ``dt`` seconds; ``width`` is σ_n in units of the
    centre spacing; ``kp_scale``/``kd_scale`` multiply the learned gains ``Ψ``.
    """

    n_basis: int = 10
    horizon: int = 100
    dt: float = 0.02
    width: float = 1.0
    kp_scale: float = 100.0
    kd_scale: float = 20.0
    W: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if int(self.n_basis) != self.n_basis or self.n_basis < 1:
            raise ValueError(f"n_basis must be an integer >= 1, got {self.n_basis!r}")
        if int(self.horizon) != self.horizon or self.horizon < 2:
            raise ValueError(f"horizon must be an integer >= 2 (control steps), got {self.horizon!r}")
        self.n_basis, self.horizon = int(self.n_basis), int(self.horizon)
        self.dt = check_positive(self.dt, "dt")
        self.width = check_positive(self.width, "width")
        self.kp_scale = check_nonneg(self.kp_scale, "kp_scale")
        self.kd_scale = check_nonneg(self.kd_scale, "kd_scale")
        if self.W is not None and np.ndim(self.W) != 2:
            raise ValueError(f"the policy's own W must be one (D, A) matrix; got shape {np.shape(self.W)}")
        self.W = self.default_params() if self.W is None else self.check_W(self.W)[0]
        # Φ on the grid t = -Δt, 0, Δt, ..., T·Δt (the two extra points serve the central difference).
        self._phi_ext = self.basis(self.dt * np.arange(-1, self.horizon + 1))

    # ----------------------------------------------------------------------------------- shapes
    @property
    def D(self) -> int:
        """Rows of ``W``: N RBF weights + 2 PD gains."""
        return self.n_basis + 2

    @property
    def n_params(self) -> int:
        """Length of the flat parameter vector, ``D · A``."""
        return self.D * A

    @property
    def duration(self) -> float:
        """Episode length in seconds, ``horizon · dt``."""
        return self.horizon * self.dt

    @property
    def centres(self) -> np.ndarray:
        """μ_n (seconds), evenly spaced over ``[0, duration]``."""
        return np.linspace(0.0, self.duration, self.n_basis)

    @property
    def sigmas(self) -> np.ndarray:
        """σ_n (seconds) = width × spacing of the centres."""
        spacing = self.duration / max(self.n_basis - 1, 1)
        return np.full(self.n_basis, self.width * spacing)

    def check_W(self, W: np.ndarray) -> np.ndarray:
        """``W`` as a float array of shape (B, D, A) (a single (D, A) matrix gets B = 1)."""
        W = np.asarray(W, dtype=float)
        if W.ndim == 2:
            W = W[None]
        if W.ndim != 3 or W.shape[1:] != (self.D, A):
            raise ValueError(f"W must have shape (D, A) = ({self.D}, {A}) or (B, {self.D}, {A}); got {W.shape}")
        if not np.all(np.isfinite(W)):
            raise ValueError("W contains non-finite values")
        return W

    # ------------------------------------------------------------------------------ parameters
    def default_params(self, kp: float = 1.0, kd: float = 1.0) -> np.ndarray:
        """(D, A) matrix with zero RBF weights (stay at the start) and PD gains ``kp``, ``kd`` (× scales)."""
        W = np.zeros((self.D, A))
        W[self.n_basis] = kp
        W[self.n_basis + 1] = kd
        return W

    def flatten(self, W: np.ndarray) -> np.ndarray:
        """(…, D, A) → (…, D·A) flat vectors (C order)."""
        W = np.asarray(W, dtype=float)
        if W.shape[-2:] != (self.D, A):
            raise ValueError(f"W must end with shape ({self.D}, {A}); got {W.shape}")
        return W.reshape(*W.shape[:-2], self.n_params)

    def unflatten(self, theta: np.ndarray) -> np.ndarray:
        """(…, D·A) flat vectors → (…, D, A) matrices."""
        theta = np.asarray(theta, dtype=float)
        if theta.shape[-1:] != (self.n_params,):
            raise ValueError(f"flat parameters must end with length {self.n_params} (= D·A); got {theta.shape}")
        return theta.reshape(*theta.shape[:-1], self.D, A)

    def get_params(self) -> np.ndarray:
        """The policy's own ``W`` as a flat vector of length ``n_params``."""
        return self.flatten(self.W).copy()

    def set_params(self, theta: np.ndarray) -> None:
        """Set the policy's own ``W`` from a flat vector of length ``n_params``."""
        self.W = self.check_W(self.unflatten(theta))[0]

    # --------------------------------------------------------------------------------- layers
    def basis(self, t: np.ndarray) -> np.ndarray:
        """Φ(t) of Eq 5.5 for times ``t`` (seconds), shape (len(t), N)."""
        t = np.asarray(t, dtype=float)[:, None]
        s = self.sigmas[None]
        return np.exp(-((t - self.centres[None]) ** 2) / (2 * s**2)) / np.sqrt(2 * np.pi * s)

    def desired(self, W: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Desired positions (Eq 5.6) and velocities (Eq 5.7) at steps 0..T-1, each (B, T, A)."""
        W = self.check_W(self.W if W is None else W)
        ext = np.matmul(self._phi_ext, W[:, : self.n_basis])  # (B, T+2, A)
        pos = ext[:, 1:-1]
        vel = (ext[:, 2:] - ext[:, :-2]) / (2 * self.dt)
        return pos, vel

    def gains(self, W: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """PD gains ``kp, kd`` of the PD layer Ψ, each (B, A)."""
        W = self.check_W(self.W if W is None else W)
        return self.kp_scale * W[:, self.n_basis], self.kd_scale * W[:, self.n_basis + 1]

    def action(self, W: np.ndarray | None, t: int, pos: np.ndarray, vel: np.ndarray) -> np.ndarray:
        """Accelerations (B, A) at control step ``t`` from observed ``pos``, ``vel`` (B, A) (Eq 5.8).

        ``simulate`` precomputes the desired trajectory instead of calling this per step; both agree.
        """
        if not 0 <= t < self.horizon:
            raise ValueError(f"t must be a control step in [0, {self.horizon}), got {t}")
        xd, vd = self.desired(W)
        kp, kd = self.gains(W)
        return kp * (xd[:, t] - pos) + kd * (vd[:, t] - vel)

    def fit(self, target: np.ndarray, kp: float = 1.0, kd: float = 1.0, ridge: float = 1e-10) -> np.ndarray:
        """Least-squares RBF weights reproducing ``target`` positions (T, A) or (B, T, A); gains set to kp, kd.

        This is the "learning from demonstration" step: ``Θ = argmin ||Φ Θ - target||²``.
        Returns ``W`` of shape (D, A) or (B, D, A).
        """
        target = np.asarray(target, dtype=float)
        single = target.ndim == 2
        tb = target[None] if single else target
        if tb.ndim != 3 or tb.shape[1:] != (self.horizon, A):
            raise ValueError(
                f"target must have shape ({self.horizon}, {A}) or (B, {self.horizon}, {A}); got {target.shape}"
            )
        phi = self._phi_ext[1:-1]
        lhs = phi.T @ phi + ridge * np.eye(self.n_basis)
        theta = np.linalg.solve(lhs, np.einsum("kn,bka->bna", phi, tb))
        W = np.empty((tb.shape[0], self.D, A))
        W[:, : self.n_basis] = theta
        W[:, self.n_basis] = kp
        W[:, self.n_basis + 1] = kd
        return W[0] if single else W

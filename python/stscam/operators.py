"""The forward model g = H f + offset as an operator: set up once, batched, with adapters.

``Operator(H, offset, object_shape)`` holds H (float32 as ``H.npz`` stores it, applied in
float64), its transpose and, on the first reconstruction, the solver's set-up (Hᵀ and the
Gram matrix HᵀH, as ``stscam reconstruct`` builds them), so many captures are reconstructed
without redoing it. Batches are stacked along the leading axes: ``forward`` takes objects
(..., h, w) and gives captures (..., rows) (or (..., *capture_shape)); ``adjoint`` the
reverse. Adapters: :meth:`Operator.scipy` (``scipy.sparse.linalg.LinearOperator``),
:meth:`Operator.torch` (an autograd function; on CPU the product runs through scipy, which is
several times faster than torch's CPU sparse product; on CUDA through ``torch.sparse``) and
:meth:`Operator.deepinv` (``deepinv.physics.LinearPhysics``). torch and deepinv are imported
only when asked for.
"""
from __future__ import annotations

import json
from typing import Any, Optional

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from . import _native


def _object_shape_of(cols: int, object_shape: Optional[Any]) -> tuple[int, int]:
    """The object's (h, w) for H with `cols` columns: `object_shape`, or the square side (of
    `cols`, else of a colour H's `cols` / 3)."""
    if object_shape is None:
        for planes in (1, 3):
            side = int(round((cols // planes) ** 0.5))
            if cols % planes == 0 and side * side * planes == cols:
                return (side, side)
        raise ValueError(f"{cols} columns are not a square object; pass object_shape=(h, w)")
    return tuple(int(v) for v in object_shape)  # type: ignore[return-value]


def _planes_of(cols: int, shape: tuple[int, int]) -> int:
    """1 for an H of h·w columns, 3 for a colour H (column blocks R, G, B of h·w each, as
    ``stscam matrix`` makes with a colour display); anything else is a ValueError."""
    n = shape[0] * shape[1]
    if n == cols:
        return 1
    if 3 * n == cols:
        return 3
    raise ValueError(f"object_shape {shape} has {n} pixels but H has {cols} columns "
                     f"(a colour H has 3·{n} = {3 * n})")


class Operator:
    """The linear forward model H (rows: capture values, columns: object pixels) with its
    offset (the capture of a black object). ``object_shape`` is (h, w) (default: square);
    ``capture_shape`` optionally shapes the captures ((h, w) or (c, h, w)). A colour H (3·h·w
    columns: blocks R, G, B) takes objects (..., 3, h, w), channel first: ``planes`` is 3 and
    ``object_dims`` (3, h, w)."""

    def __init__(self, H: Any, offset: Any = None, object_shape: Optional[tuple[int, int]] = None,
                 capture_shape: Optional[tuple[int, ...]] = None, threads: Optional[int] = None):
        if not scipy.sparse.issparse(H):
            raise ValueError(f"H: expected a scipy sparse matrix, got {type(H).__name__}")
        h = scipy.sparse.csr_matrix(H, dtype=np.float32, copy=True)
        h.sum_duplicates()
        h.sort_indices()
        if not np.all(np.isfinite(h.data)):
            raise ValueError("H: an entry is not a finite number")
        rows, cols = h.shape
        oh, ow = _object_shape_of(cols, object_shape)
        planes = _planes_of(cols, (oh, ow))
        if capture_shape is not None and int(np.prod(capture_shape)) != rows:
            raise ValueError(f"capture_shape {tuple(capture_shape)} has {int(np.prod(capture_shape))} values but H has {rows} rows")
        self.H: scipy.sparse.csr_matrix = h  #: float32 CSR, as H.npz
        self._h64 = h.astype(np.float64)
        self._ht64 = self._h64.T.tocsr()
        if offset is None:
            self.offset = np.zeros(rows, np.float32)
        else:
            self.offset = np.ascontiguousarray(np.asarray(offset, dtype=np.float32).reshape(-1))
            if self.offset.size != rows:
                raise ValueError(f"offset: {self.offset.size} values but H has {rows} rows")
            if not np.all(np.isfinite(self.offset)):
                i = int(np.flatnonzero(~np.isfinite(self.offset))[0])
                raise ValueError(f"offset: value {i} is not a finite number")
        self.object_shape: tuple[int, int] = (oh, ow)
        self.planes: int = planes  #: 1, or 3 for a colour H
        #: The shape of one object: (h, w), or (3, h, w) for a colour H.
        self.object_dims: tuple[int, ...] = (oh, ow) if planes == 1 else (3, oh, ow)
        self.capture_shape: tuple[int, ...] = (rows,) if capture_shape is None else tuple(int(v) for v in capture_shape)
        self.shape: tuple[int, int] = (rows, cols)
        self.threads = threads
        self._solver: Any = None

    # --- products ---
    def forward(self, f: Any) -> np.ndarray:
        """H f for objects (..., h, w) (or (..., h·w)): float64 captures (..., *capture_shape),
        without the offset (see :meth:`capture`)."""
        x = np.asarray(f, dtype=np.float64)
        lead = self._lead(x, self.object_dims, "object")
        flat = x.reshape(-1, self.shape[1])
        # One frame: scipy's matrix-vector product (faster than a one-column product, same sums).
        y = (self._h64 @ flat[0])[None] if flat.shape[0] == 1 else (self._h64 @ flat.T).T
        return y.reshape(lead + self.capture_shape)

    def capture(self, f: Any) -> np.ndarray:
        """The noiseless capture H f + offset (float64), as ``stscam dataset`` computes it."""
        return self.forward(f) + self.offset.astype(np.float64).reshape(self.capture_shape)

    def adjoint(self, g: Any) -> np.ndarray:
        """Hᵀ g for captures (..., *capture_shape) (or (..., rows)): float64 (..., h, w)."""
        y = np.asarray(g, dtype=np.float64)
        lead = self._lead(y, self.capture_shape, "capture")
        flat = y.reshape(-1, self.shape[0])
        x = (self._ht64 @ flat[0])[None] if flat.shape[0] == 1 else (self._ht64 @ flat.T).T
        return x.reshape(lead + self.object_dims)

    def _lead(self, a: np.ndarray, shape: tuple[int, ...], what: str) -> tuple[int, ...]:
        n = int(np.prod(shape))
        if a.shape[-len(shape):] == tuple(shape):
            return a.shape[:-len(shape)]
        if a.ndim >= 1 and a.shape[-1] == n:
            return a.shape[:-1]
        raise ValueError(f"{what}: shape {a.shape} does not end in {tuple(shape)} or {n}")

    # --- reconstruction ---
    def reconstruct(self, capture: Any, method: str = "admm-tv", iters: Optional[int] = None,
                    tau: Optional[float] = None, tv: str = "iso", subtract_offset: bool = True,
                    return_info: bool = False, regularisation: str = "discrepancy",
                    sensor: Any = None, white_peak: Optional[float] = None) -> Any:
        """Reconstructs each capture (..., *capture_shape) with CG (``method="cg"``) or
        ADMM-TV, exactly as :func:`stscam.reconstruct` (and ``stscam reconstruct``) does, the
        set-up made once per operator: float64 objects (..., h, w); with ``return_info`` also
        the solver reports (a list, one per capture). ``regularisation``, ``sensor`` and
        ``white_peak`` as :func:`stscam.reconstruct` (default: the discrepancy principle on
        the default scene's sensor, the exposure from max(H·1 + offset)); the black level is
        the operator's offset either way."""
        from . import _rule_args, _threads, _uint
        rule = _rule_args(regularisation, tau, sensor, white_peak)
        g = np.asarray(capture, dtype=np.float64)
        lead = self._lead(g, self.capture_shape, "capture")
        g = g.reshape(-1, self.shape[0])
        if subtract_offset:
            g = g - self.offset.astype(np.float64)
        if self._solver is None:
            h = self.H
            self._solver = _native.Solver(
                h.shape[0], h.shape[1], h.indptr.astype("<i8").tobytes(),
                h.indices.astype("<i8").tobytes(), h.data.astype("<f4").tobytes(),
                (self.object_shape[1], self.object_shape[0]), _threads(self.threads),
                self.planes)
        f, infos = self._solver.solve(
            np.ascontiguousarray(g, dtype="<f8").tobytes(), g.shape[0], method,
            None if iters is None else _uint(iters, "--iters <ITERS>", 2**64 - 1),
            0.001 if tau is None else float(tau), tv, _threads(self.threads),
            self.offset.astype("<f4").tobytes(), *rule)
        obj = np.frombuffer(f, dtype="<f8").reshape(lead + self.object_dims).astype(np.float64)
        return (obj, [json.loads(i) for i in infos]) if return_info else obj

    # --- adapters ---
    def scipy(self) -> scipy.sparse.linalg.LinearOperator:
        """H as a ``scipy.sparse.linalg.LinearOperator`` on flat vectors (float64)."""
        rows, cols = self.shape
        return scipy.sparse.linalg.LinearOperator(
            (rows, cols), dtype=np.float64,
            matvec=lambda x: self._h64 @ np.asarray(x, np.float64).reshape(-1),
            rmatvec=lambda y: self._ht64 @ np.asarray(y, np.float64).reshape(-1),
            matmat=lambda X: self._h64 @ np.asarray(X, np.float64),
            rmatmat=lambda Y: self._ht64 @ np.asarray(Y, np.float64))

    def torch(self) -> Any:
        """A function ``A(x)`` for torch tensors (..., h, w) → (..., *capture_shape) (the
        linear part, H x), differentiable (its backward is the adjoint), and its adjoint as
        ``A.adjoint``. CPU tensors go through scipy; CUDA tensors through a ``torch.sparse``
        copy of H made on first use on that device."""
        import torch
        return _torch_operator(self, torch)

    def deepinv(self, noise_model: Any = None, sensor: Any = None, seed: int = 1,
                white_peak: Optional[float] = None) -> Any:
        """A ``deepinv.physics.LinearPhysics`` with A = H (the offset subtracted from
        measurements first) and A_adjoint = Hᵀ, on tensors (B, C, h, w) → (B, 1, rows) (C = 1, or
        3 for a colour H).

        ``sensor=scene`` gives it the scene's sensor noise (shot, read, dark, bit depth,
        saturation, exposure: :func:`stscam.sensor_noise`) as its noise model: a measurement
        y = A x becomes sensor_noise(y + offset) − offset, image b of the i-th noisy call with
        seed ``seed + i·B + b`` (or ``seed`` + b when deepinv passes one), so a run is
        reproducible. ``noise_model`` takes any deepinv noise model instead."""
        import deepinv
        import torch
        A = _torch_operator(self, torch)
        if sensor is not None:
            if noise_model is not None:
                raise ValueError("deepinv: pass noise_model or sensor, not both")
            noise_model = _sensor_noise_model(self, sensor, int(seed), white_peak, deepinv, torch)
        kw = {} if noise_model is None else {"noise_model": noise_model}
        rows = self.shape[0]
        oh, ow = self.object_shape
        c = self.planes
        return deepinv.physics.LinearPhysics(
            A=lambda x: A(x.reshape((x.shape[0],) + self.object_dims)).reshape(x.shape[0], 1, rows),
            A_adjoint=lambda y: A.adjoint(y.reshape(y.shape[0], rows)).reshape(y.shape[0], c, oh, ow),
            **kw)

    def __repr__(self) -> str:
        return f"Operator({self.shape[0]}x{self.shape[1]}, nnz={self.H.nnz}, object_shape={self.object_shape})"


def _sensor_noise_model(op: Operator, scene: Any, seed: int, white_peak: Optional[float],
                        deepinv: Any, torch: Any) -> Any:
    """The deepinv noise model of :meth:`Operator.deepinv` (``sensor=``)."""
    from . import _scene, _white_peak, sensor_noise

    scene = _scene(scene)
    if white_peak is None:
        white_peak = _white_peak(scene)  # once, not per call

    class SensorNoise(deepinv.physics.NoiseModel):  # type: ignore[misc, name-defined]
        def __init__(self) -> None:
            super().__init__()
            self.calls = 0

        def forward(self, x: Any, seed: Optional[int] = None, **kwargs: Any) -> Any:
            flat = x.detach().to(torch.float64).cpu().numpy().reshape(x.shape[0], -1)
            base = (seed_base + self.calls * x.shape[0]) if seed is None else int(seed)
            self.calls += 1
            off = op.offset.astype(np.float64)
            noisy = np.stack([
                sensor_noise(scene, g + off, seed=base + b, white_peak=white_peak).reshape(-1) - off
                for b, g in enumerate(flat)])
            return torch.from_numpy(noisy).to(dtype=x.dtype, device=x.device).reshape(x.shape)

    seed_base = seed
    return SensorNoise()


def _torch_operator(op: Operator, torch: Any) -> Any:
    """The autograd function of :meth:`Operator.torch`."""
    cache: dict[Any, Any] = {}

    def sparse_on(device: Any, dtype: Any, transpose: bool) -> Any:
        key = (str(device), dtype, transpose)
        if key not in cache:
            m = (op._ht64 if transpose else op._h64).tocoo()
            idx = torch.tensor(np.vstack([m.row, m.col]), dtype=torch.int64)
            cache[key] = torch.sparse_coo_tensor(idx, torch.tensor(m.data), m.shape).to(dtype=dtype, device=device).coalesce().to_sparse_csr()
        return cache[key]

    def apply(x: Any, transpose: bool) -> Any:
        n_in = op.shape[0] if transpose else op.shape[1]
        out_shape = op.object_dims if transpose else op.capture_shape
        in_shape = op.capture_shape if transpose else op.object_dims
        lead = x.shape[:-len(in_shape)] if tuple(x.shape[-len(in_shape):]) == tuple(in_shape) \
            else x.shape[:-1]
        flat = x.reshape(-1, n_in)
        if x.device.type == "cpu":
            m = op._ht64 if transpose else op._h64
            y = torch.from_numpy((m @ flat.detach().to(torch.float64).numpy().T).T.copy()).to(x.dtype)
        else:
            y = (sparse_on(x.device, x.dtype, transpose) @ flat.T).T
        return y.reshape(tuple(lead) + tuple(out_shape))

    class _H(torch.autograd.Function):
        @staticmethod
        def forward(ctx: Any, x: Any) -> Any:
            return apply(x, False)

        @staticmethod
        def backward(ctx: Any, grad: Any) -> Any:
            return apply(grad, True)

    class _Ht(torch.autograd.Function):
        @staticmethod
        def forward(ctx: Any, y: Any) -> Any:
            return apply(y, True)

        @staticmethod
        def backward(ctx: Any, grad: Any) -> Any:
            return apply(grad, False)

    def A(x: Any) -> Any:
        return _H.apply(x)

    A.adjoint = _Ht.apply  # type: ignore[attr-defined]
    return A

from typing import Any, Optional

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

class Operator:
    H: scipy.sparse.csr_matrix
    offset: np.ndarray
    object_shape: tuple[int, int]
    planes: int
    object_dims: tuple[int, ...]
    capture_shape: tuple[int, ...]
    shape: tuple[int, int]
    threads: Optional[int]
    def __init__(self, H: Any, offset: Any = None, object_shape: Optional[tuple[int, int]] = None,
                 capture_shape: Optional[tuple[int, ...]] = None,
                 threads: Optional[int] = None) -> None: ...
    def forward(self, f: Any) -> np.ndarray: ...
    def capture(self, f: Any) -> np.ndarray: ...
    def adjoint(self, g: Any) -> np.ndarray: ...
    def reconstruct(self, capture: Any, method: str = "admm-tv", iters: Optional[int] = None,
                    tau: Optional[float] = None, tv: str = "iso", subtract_offset: bool = True,
                    return_info: bool = False, regularisation: str = "discrepancy",
                    sensor: Any = None, white_peak: Optional[float] = None) -> Any: ...
    def scipy(self) -> scipy.sparse.linalg.LinearOperator: ...
    def torch(self) -> Any: ...
    def deepinv(self, noise_model: Any = None, sensor: Any = None, seed: int = 1,
                white_peak: Optional[float] = None) -> Any: ...

import os
from typing import Any, Optional

import numpy as np
import scipy.sparse

SPLITS: tuple[str, str, str]

class Dataset:
    root: str
    split: str
    dir: str
    transform: Any
    metadata: list[dict[str, Any]]
    card: Optional[dict[str, Any]]
    kind: str
    capture_full_scale: Optional[float]
    def __init__(self, root: str | os.PathLike[str], split: str = "train", transform: Any = None) -> None: ...
    def __len__(self) -> int: ...
    def __getitem__(self, i: int) -> dict[str, Any]: ...
    def matrix(self, i: int) -> Optional[tuple[scipy.sparse.csr_matrix, np.ndarray]]: ...

def load_dataset(path: str | os.PathLike[str], split: str = "train", transform: Any = None) -> Dataset: ...
def load_splits(path: str | os.PathLike[str]) -> dict[str, Dataset]: ...

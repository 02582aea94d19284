"""Type stubs of the stscam Python package (see __init__.py for the documentation)."""
import os
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import scipy.sparse

from .dataset import Dataset as Dataset, load_dataset as load_dataset, load_splits as load_splits
from .operators import Operator as Operator

__version__: str
__all__ = [
    "Scene", "Render", "Frontal", "render", "render_batch", "matrix", "matrix_stack",
    "reconstruct_stack", "info", "probe", "reconstruct", "calibrate", "sweep", "evaluate",
    "optimize", "Optimization", "build_dataset",
    "merge_dataset", "load_dataset", "load_splits", "Dataset", "target", "sensor_noise",
    "Operator", "read_exr", "write_exr", "scenes", "to_toml", "__version__",
]

def target(spec: str) -> np.ndarray: ...
def to_toml(d: Mapping[str, Any]) -> str: ...
def scenes() -> list[str]: ...

class Scene:
    path: Optional[str]
    overrides: dict[str, Any]
    image: Optional[np.ndarray]
    encoding: Optional[str]
    def __init__(self, path: Optional[str | os.PathLike[str]] = None,
                 overrides: Optional[Mapping[str, Any]] = None, image: Any = None,
                 encoding: Optional[str] = None,
                 _text: Optional[tuple[str, str, str]] = None) -> None: ...
    @classmethod
    def named(cls, name: str, overrides: Optional[Mapping[str, Any]] = None) -> Scene: ...
    @classmethod
    def from_dict(cls, d: Mapping[str, Any], overrides: Optional[Mapping[str, Any]] = None,
                  base_dir: str | os.PathLike[str] = ".", image: Any = None,
                  encoding: Optional[str] = None) -> Scene: ...
    def with_image(self, image: Any, encoding: str) -> Scene: ...
    @property
    def sets(self) -> list[str]: ...
    def to_dict(self) -> dict[str, Any]: ...
    def coverage_warning(self) -> Optional[str]: ...

@dataclass
class Frontal:
    image: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    channels: list[str] = ...
    space: str = ...

@dataclass
class Render:
    image: np.ndarray
    channels: list[str]
    stats: dict[str, Any]
    render_time_s: float
    spectral: Optional[np.ndarray] = None
    spectral_bins_nm: list[float] = ...
    frontal_result: Optional[Frontal] = None
    @property
    def frontal(self) -> Optional[np.ndarray]: ...
    @property
    def depth(self) -> Optional[np.ndarray]: ...
    @property
    def mask(self) -> Optional[np.ndarray]: ...

def render(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
           threads: Optional[int] = None, sampler: str = "lattice", spectral: bool = False,
           frontal_px: Any = None, user_side: str = "auto", target: Any = None,
           encoding: Optional[str] = None, noise: Optional[str] = None,
           white_peak: Optional[float] = None, frontal_space: str = "sensor",
           progress: Optional[Callable[[int, int, str], Any]] = None,
           camera_table: Optional[str | os.PathLike] = None, table_spp: int = 1024,
           table_reps: int = 32, frontal_spp: Optional[int] = None,
           adaptive: bool = False) -> Render: ...
def render_batch(scene: Optional[Scene], targets: Any, encoding: Optional[str] = None,
                 spp: int = 64, seed: int = 1, threads: Optional[int] = None,
                 sampler: str = "lattice", user_side: str = "auto",
                 noise: Optional[str] = None, white_peak: Optional[float] = None,
                 progress: Optional[Callable[[int, int, str], Any]] = None,
                 camera_table: Optional[str | os.PathLike] = None, table_spp: int = 1024,
                 table_reps: int = 32, adaptive: bool = False) -> np.ndarray: ...
def sensor_noise(scene: Optional[Scene], clean: Any, seed: int = 1,
                 white_peak: Optional[float] = None) -> np.ndarray: ...
def matrix(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
           depth_mm: Optional[float] = None,
           threads: Optional[int] = None,
           progress: Optional[Callable[[int, int, str], Any]] = None) -> tuple[scipy.sparse.csr_matrix, np.ndarray]: ...
def matrix_stack(scene: Optional[Scene] = None, depth_mm: str | Sequence[float] = "300:650:8",
                 spp: int = 64, seed: int = 1, threads: Optional[int] = None,
                 progress: Optional[Callable[[int, int, str], Any]] = None
                 ) -> list[tuple[float, scipy.sparse.csr_matrix, np.ndarray]]: ...
def info(scene: Optional[Scene] = None) -> dict[str, Any]: ...
def probe(scene: Optional[Scene] = None, pixel: tuple[int, int] = (0, 0)) -> dict[str, Any]: ...
def reconstruct(H: Any, capture: Any, method: str = "admm-tv", iters: Optional[int] = None,
                tau: Optional[float] = None, offset: Any = None, tv: str = "iso",
                object_shape: Optional[tuple[int, int]] = None, threads: Optional[int] = None,
                return_info: bool = False, regularisation: str = "discrepancy",
                sensor: Optional[Scene] = None, white_peak: Optional[float] = None) -> Any: ...
def reconstruct_stack(stack: Sequence[tuple[float, Any, Any]], capture: Any, method: str = "joint",
                      iters: Optional[int] = None, tau: Optional[float] = None,
                      mu: Optional[float] = None, offset: Any = None, tv: str = "iso",
                      object_shape: Optional[tuple[int, int]] = None,
                      threads: Optional[int] = None) -> dict[str, Any]: ...
def calibrate(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
              matrix: Optional[str | os.PathLike[str]] = None,
              object_shape: Optional[tuple[int, int]] = None, noise: str = "sensor",
              dark_frame: bool = False, render: bool = False, threshold_sigma: float = 5.0,
              threads: Optional[int] = None,
              progress: Optional[Callable[[int, int, str], Any]] = None) -> tuple[scipy.sparse.csr_matrix, dict[str, Any]]: ...
def sweep(scene: Optional[Scene] = None,
          vary: Sequence[str] | Mapping[str, tuple[float, float, int]] = (),
          fov_fraction: float = 0.1, psnr: Optional[str] = None, psnr_spp: int = 64,
          threads: Optional[int] = None,
          progress: Optional[Callable[[int, int, str], Any]] = None) -> list[dict[str, Any]]: ...
def evaluate(scene: Optional[Scene] = None, metrics: Sequence[str] | str = ("psnr_db",),
             targets: Optional[Sequence[Any]] = None, encoding: Optional[str] = None,
             depth_mm: Any = None, object_px: int = 32, binning: int = 2, spp: int = 8,
             replicates: int = 2, white_peak: Optional[float] = None,
             draw: Sequence[str] = (), draws: int = 64, require: Sequence[str] = (),
             seed: int = 1, threads: Optional[int] = None,
             progress: Optional[Callable[[int, int, str], Any]] = None) -> dict[str, float]: ...
class Optimization:
    history: list[dict[str, Any]]
    summary: dict[str, Any]
    best: Optional[int]
    pareto: list[int]
    best_scene: Optional[Scene]
    out: Optional[str]
    def __init__(self, history: list[dict[str, Any]], summary: dict[str, Any],
                 best_scene: Optional[Scene], out: Optional[str]) -> None: ...
    def params(self) -> np.ndarray: ...
    def metric(self, name: str) -> np.ndarray: ...
def optimize(study: str | os.PathLike[str] | Mapping[str, Any], budget: int = 40, seed: int = 1,
             out: Optional[str | os.PathLike[str]] = None, resume: bool = False,
             skip_final: bool = False, threads: Optional[int] = None,
             progress: Optional[Callable[[int, int, str], Any]] = None,
             base_dir: str | os.PathLike[str] = ".") -> Optimization: ...
def build_dataset(recipe: str | os.PathLike[str], out: str | os.PathLike[str],
                  shard: Optional[str | tuple[int, int]] = None, resume: bool = False,
                  threads: Optional[int] = None,
                  progress: Optional[Callable[[int, int, str], Any]] = None,
                  objects: Any = None, encoding: Optional[str] = None) -> dict[str, Any]: ...
def merge_dataset(shards: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str],
                  threads: Optional[int] = None) -> dict[str, Any]: ...
def read_exr(path: str | os.PathLike[str]) -> dict[str, np.ndarray]: ...
def write_exr(path: str | os.PathLike[str], channels: Mapping[str, Any]) -> None: ...

"""Reading a dataset made by ``stscam dataset`` (layout: docs/datasets.md), with numpy.

Every kind of dataset loads: 2-D (object and capture), planar objects over depth (also the
sample's ``depth_mm``) and 3-D scenes (capture, frontal image, depth map and mask). Each
sample states the capture's scale (``capture_full_scale``, the card's exposure: the capture
value a 16-bit PNG maps to 65535). The reader stays inside the dataset folder: a
``metadata.jsonl`` naming a file outside it (an absolute path, ``..`` past the root or a
symbolic link leading out) is refused with ``ValueError``, as are files that are not regular
files (FIFOs, devices) or larger than the CLI accepts.
"""
from __future__ import annotations

import json
import os
from typing import Any, Optional

import numpy as np

#: The split names, as the Hugging Face loader names them; ``"val"`` (the folder's name) is
#: accepted for ``"validation"``.
SPLITS = ("train", "validation", "test")
_FOLDER = {"train": "train", "validation": "val", "val": "val", "test": "test"}
# The CLI's bounds on what it reads whole (sim/io/src/input.rs): text 64 MiB, binary 4 GiB.
_MAX_TEXT_BYTES = 64 << 20
_MAX_BINARY_BYTES = 4 << 30


def _regular_file(path: str, max_bytes: int) -> str:
    """``path`` if it is a regular file of at most ``max_bytes`` bytes, else ValueError with
    the CLI's wording."""
    try:
        st = os.stat(path)
    except OSError as e:
        raise ValueError(f"{path}: {e.strerror}") from None
    import stat
    if not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else (
            "a FIFO (named pipe)" if stat.S_ISFIFO(st.st_mode) else (
                "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a regular file"))
        raise ValueError(f"{path}: is {kind}, not a regular file")
    if st.st_size > max_bytes:
        raise ValueError(f"{path}: is {st.st_size} bytes, more than the {max_bytes} bytes accepted for this input")
    return path


class Dataset:
    """One split of a dataset: ``len(ds)`` samples, ``ds[i]`` a dict of numpy arrays and
    numbers, ``ds.metadata[i]`` the sample's ``metadata.jsonl`` line, ``ds.card`` the
    ``dataset.json`` card. ``ds.kind`` is ``"2d"``, ``"depth"`` or ``"3d"``; a sample holds

    * every kind: ``"capture"`` (float32 [h, w] or [c, h, w], capture units), ``"index"`` and
      ``"capture_full_scale"`` (the capture value shown as white in the capture PNG; 1 is a
      white display pixel seen by an on-axis pixel through lossless optics);
    * 2-D and depth: ``"object"`` (float32 [h, w], linear intensity, the vector of g = H f);
      depth also ``"depth_mm"`` (the object plane's distance);
    * 3-D: ``"frontal"`` (float32 [h, w] or [c, h, w], 1 = display white), ``"depth"``
      (float32 [h, w], mm, ``inf`` where nothing is hit) and ``"mask"`` (uint16 [h, w]: object
      index + 1, 65535 the display, 0 nothing).

    Wrap it in a ``torch.utils.data.DataLoader`` as it is (the default collate stacks the
    arrays; ``transform``, if given, is applied to each sample dict)."""

    def __init__(self, root: str | os.PathLike[str], split: str = "train", transform: Any = None):
        if split not in _FOLDER:
            raise ValueError(f"split {split!r}: expected one of {', '.join(SPLITS)} (or \"val\")")
        self.root = os.fspath(root)
        self.split = "validation" if split == "val" else split
        self.dir = os.path.join(self.root, _FOLDER[split])
        self.transform = transform
        self._real_root = os.path.realpath(self.root)
        meta = os.path.join(self.dir, "metadata.jsonl")
        if not os.path.exists(meta):
            raise ValueError(f"{meta}: missing; not a dataset made by `stscam dataset`")
        with open(_regular_file(meta, _MAX_TEXT_BYTES), encoding="utf-8") as f:
            self.metadata: list[dict[str, Any]] = [json.loads(line) for line in f if line.strip()]
        for m in self.metadata:
            if not isinstance(m, dict) or not isinstance(m.get("capture_npy"), str):
                raise ValueError(f"{meta}: a line without capture_npy; not a dataset made by `stscam dataset`")
        card = os.path.join(self.root, "dataset.json")
        self.card: Optional[dict[str, Any]] = None
        if os.path.exists(card):
            with open(_regular_file(card, _MAX_TEXT_BYTES), encoding="utf-8") as f:
                self.card = json.load(f)
        first = self.metadata[0] if self.metadata else {}
        self.kind: str = "3d" if "frontal_npy" in first else ("depth" if "depth_mm" in first else "2d")
        exposure = (self.card or {}).get("exposure") or {}
        self.capture_full_scale: Optional[float] = exposure.get("capture_full_scale")

    def _path(self, rel: Any, key: str, max_bytes: int = _MAX_BINARY_BYTES) -> str:
        """The file a metadata entry names, refused unless it lies inside the dataset folder."""
        where = f"{os.path.join(self.dir, 'metadata.jsonl')}: {key}"
        if not isinstance(rel, str) or not rel or os.path.isabs(rel) or "\0" in rel:
            raise ValueError(f"{where} {rel!r}: expected a relative path inside the dataset folder")
        path = os.path.join(self.dir, rel)
        real = os.path.realpath(path)
        if os.path.commonpath([real, self._real_root]) != self._real_root:
            raise ValueError(f"{where} {rel!r}: leads outside the dataset folder {self.root}")
        return _regular_file(path, max_bytes)

    def _npy(self, m: dict[str, Any], key: str) -> np.ndarray:
        path = self._path(m.get(key), key)
        a = np.load(path, allow_pickle=False)
        if a.dtype != np.float32:
            raise ValueError(f"{path}: {a.dtype}, expected float32")
        return a

    def __len__(self) -> int:
        return len(self.metadata)

    def __getitem__(self, i: int) -> dict[str, Any]:
        i = int(i)
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        m = self.metadata[i]
        item: dict[str, Any] = {"capture": self._npy(m, "capture_npy")}
        if self.kind == "3d":
            from . import _native
            item["frontal"] = self._npy(m, "frontal_npy")
            item["depth"] = self._npy(m, "depth_npy")
            w, h, ch, b = _native.read_png16(self._path(m.get("mask_file_name"), "mask_file_name"))
            if ch != 1:
                raise ValueError(f"{m.get('mask_file_name')}: a mask has 1 channel, this PNG {ch}")
            item["mask"] = np.frombuffer(b, dtype="<u2").reshape(h, w).astype(np.uint16)
        else:
            item["object"] = self._npy(m, "object_npy")
            if "depth_mm" in m:
                item["depth_mm"] = float(m["depth_mm"])
        item["index"] = i % len(self)
        if self.capture_full_scale is not None:
            item["capture_full_scale"] = float(self.capture_full_scale)
        return self.transform(item) if self.transform is not None else item

    def matrix(self, i: int) -> Optional[tuple[Any, np.ndarray]]:
        """(H, offset) of sample ``i``'s scene (scipy CSR, float32 vector), or None for a
        render-mode dataset without H."""
        import scipy.sparse
        rel = self.metadata[i].get("matrix")
        if not rel:
            return None
        path = self._path(rel, "matrix")
        off = self._path(os.path.join(os.path.dirname(rel), "offset.npy"), "matrix")
        return scipy.sparse.load_npz(path).tocsr(), np.load(off, allow_pickle=False)


def load_dataset(path: str | os.PathLike[str], split: str = "train", transform: Any = None) -> Dataset:
    """Opens one split (``"train"``, ``"validation"`` (or ``"val"``) or ``"test"``) of a
    dataset folder of any kind (2-D, depth or 3-D)."""
    return Dataset(path, split, transform)


def load_splits(path: str | os.PathLike[str]) -> dict[str, Dataset]:
    """Every non-empty split of a dataset folder by its Hugging Face name (``train``,
    ``validation``, ``test``), as ``datasets.load_dataset("imagefolder", ...)`` names them."""
    root = os.fspath(path)
    out = {s: Dataset(root, s) for s in SPLITS if os.path.exists(os.path.join(root, _FOLDER[s], "metadata.jsonl"))}
    if not out:
        raise ValueError(f"{root}: no split holds a metadata.jsonl; not a dataset made by `stscam dataset`")
    return out

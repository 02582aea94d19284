"""Reading a dataset made by ``stscam dataset`` (layout: README, "Datasets"): numpy only."""
from __future__ import annotations

import json
import os
from typing import Optional

import numpy as np

SPLITS = ("train", "val", "test")


class Dataset:
    """One split of a dataset: ``len(ds)`` samples, ``ds[i]`` a dict with ``"object"``
    (float32 [h, w], linear intensity), ``"capture"`` (float32 [h, w] or [c, h, w]) and
    ``"index"``; ``ds.metadata[i]`` is the sample's ``metadata.jsonl`` line. Wrap it in a
    ``torch.utils.data.DataLoader`` as it is (the default collate stacks the arrays)."""

    def __init__(self, root: str | os.PathLike, split: str = "train"):
        if split not in SPLITS:
            raise ValueError(f"split {split!r}: expected one of {', '.join(SPLITS)}")
        self.root = os.fspath(root)
        self.split = split
        self.dir = os.path.join(self.root, split)
        meta = os.path.join(self.dir, "metadata.jsonl")
        if not os.path.isfile(meta):
            raise ValueError(f"{meta}: missing; not a dataset made by `stscam dataset`")
        with open(meta, encoding="utf-8") as f:
            self.metadata: list[dict] = [json.loads(line) for line in f if line.strip()]
        card = os.path.join(self.root, "dataset.json")
        self.card: Optional[dict] = None
        if os.path.isfile(card):
            with open(card, encoding="utf-8") as f:
                self.card = json.load(f)

    def __len__(self) -> int:
        return len(self.metadata)

    def __getitem__(self, i: int) -> dict:
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} samples")
        m = self.metadata[i]
        return {
            "object": np.load(os.path.join(self.dir, m["object_npy"])),
            "capture": np.load(os.path.join(self.dir, m["capture_npy"])),
            "index": i % len(self),
        }

    def matrix(self, i: int):
        """(H, offset) of sample ``i``'s scene (scipy CSR, float32 vector), or None for a
        render-mode dataset without H."""
        import scipy.sparse
        rel = self.metadata[i].get("matrix")
        if not rel:
            return None
        path = os.path.normpath(os.path.join(self.dir, rel))
        off = os.path.join(os.path.dirname(path), "offset.npy")
        return scipy.sparse.load_npz(path), np.load(off)


def load_dataset(path: str | os.PathLike, split: str = "train") -> Dataset:
    """Opens one split (``"train"``, ``"val"`` or ``"test"``) of a dataset folder."""
    return Dataset(path, split)

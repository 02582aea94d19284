"""stscam: the see-through-screen camera simulator (holographic waveguide, Optics Express 2022).

A thin Python front end over the same Rust library as the ``stscam`` command line: for the same
inputs every function returns the numbers the CLI writes, bit for bit (``render`` ↔
``capture.exr``, ``matrix`` ↔ ``H.npz`` and ``offset.npy``, ``info``/``probe`` ↔ ``--json``).
Bad input raises ``ValueError`` with the CLI's one-line message. Long calls release the GIL
and stop on Ctrl-C (``KeyboardInterrupt``). Millimetres throughout; images have row 0 at the top
and column 0 at the left as seen from the camera.
"""
from __future__ import annotations

import json
import operator
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Optional, Sequence

import numpy as np
import scipy.sparse

from . import _native
from .dataset import Dataset, load_dataset, load_splits
from .operators import Operator, _object_shape_of, _planes_of

__all__ = [
    "Scene", "Render", "Frontal", "render", "render_batch", "matrix", "matrix_stack",
    "reconstruct_stack", "info", "probe", "reconstruct", "calibrate", "sweep", "evaluate",
    "optimize", "Optimization", "build_dataset",
    "merge_dataset", "load_dataset", "load_splits", "Dataset", "target", "sensor_noise", "Operator",
    "read_exr", "write_exr", "scenes", "to_toml", "__version__",
]
__version__: str = _native.VERSION


def _toml_value(v: Any) -> str:
    """A Python value as a TOML literal for a ``--set KEY=VALUE`` override."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float, np.integer, np.floating)):
        return repr(float(v)) if isinstance(v, (float, np.floating)) else str(int(v))
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise ValueError(f"--set: cannot express {v!r} ({type(v).__name__}) as a TOML value")


_U32 = 2**32 - 1
_U64 = 2**64 - 1


def _uint(v: Any, flag: str, hi: int, lo: int = 0) -> int:
    """An integer argument checked as the CLI's parser checks ``flag`` (``--spp <SPP>``):
    ValueError with its message for a non-integer or a value outside ``lo..=hi`` (never
    OverflowError)."""
    try:
        if isinstance(v, bool):
            raise TypeError
        i = operator.index(v)
    except TypeError:
        raise ValueError(f"invalid value '{v}' for '{flag}': expected an integer") from None
    if not lo <= i <= hi:
        raise ValueError(f"invalid value '{v}' for '{flag}': {i} is not in {lo}..={hi}")
    return i


def _progress(progress: Optional[Callable[[int, int, str], Any]]) -> Optional[Callable[[int, int, str], Any]]:
    """A ``progress`` argument: None or a callable ``progress(done, total, unit)``, called on
    the calling thread about every 0.1 s while the count of the job's units changes, and once
    at the end. ``unit`` names them ("samples", "rows", "calibration frames", ...); a job of
    several phases (a depth dataset: its matrix stack, then its samples) reports each phase
    from 0 to its own total. An exception from the callback stops the job and is raised."""
    if progress is not None and not callable(progress):
        raise ValueError(f"progress: expected a callable progress(done, total, unit) or None, got {type(progress).__name__}")
    return progress


def _check_arrays(items: Any, what: str, extra_bytes_each: int = 0,
                  max_count: Optional[int] = None) -> int:
    """Refuses a batch of arrays before any is converted: more than ``max_count`` of them, or
    more than one job's memory (stscam's limit) in their float32 values plus
    ``extra_bytes_each`` per item (e.g. each item's output). Returns the count."""
    try:
        n = len(items)
    except TypeError:
        raise ValueError(f"{what}: expected an array or a sequence of arrays, got "
                         f"{type(items).__name__}") from None
    if max_count is not None and n > max_count:
        raise ValueError(f"{what}: {n} arrays, at most {max_count}")
    limit = int(_native.MAX_JOB_BYTES)
    total = 0
    if isinstance(items, np.ndarray) and items.ndim >= 1:
        total = n * (int(np.prod(items.shape[1:])) * 4 + extra_bytes_each)
    else:
        for t in items:
            total += int(np.prod(np.shape(t))) * 4 + extra_bytes_each
            if total > limit:
                break
    if total > limit:
        raise ValueError(f"{what}: {n} arrays need more than {limit >> 30} GiB (the memory "
                         f"limit of one job); pass fewer or smaller ones")
    return n


def _threads(threads: Any) -> Optional[int]:
    return None if threads is None else _uint(threads, "--threads <THREADS>", _U64)


def _image_arg(image: Any, encoding: Optional[str], what: str = "image"):
    """A target array as the extension takes it: (w, h, channels, float32 bytes, linear).

    ``image`` is (h, w) or (h, w, 3) (or (h, w, 1)); floats are taken as they are, unsigned
    integers as code values over their maximum (uint8 / 255, uint16 / 65535), booleans as 0/1.
    ``encoding`` must say what the values are: ``"linear"`` (linear intensity, as an EXR) or
    ``"display"`` (display code values in [0, 1]; the display gamma is applied, as for a PNG)."""
    if encoding not in ("linear", "display"):
        raise ValueError(f"{what}: encoding {encoding!r}: pass encoding=\"linear\" (linear intensity, "
                         "as an EXR) or encoding=\"display\" (code values, display gamma applied, as a PNG)")
    a = np.asarray(image)
    if a.dtype == bool:
        a = a.astype(np.float32)
    elif a.dtype.kind == "u":
        a = (a.astype(np.float64) / float(np.iinfo(a.dtype).max)).astype(np.float32)
    elif a.dtype.kind == "f":
        a = a.astype(np.float32)
    else:
        raise ValueError(f"{what}: dtype {a.dtype}: expected a float, unsigned integer or bool array")
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise ValueError(f"{what}: shape {a.shape}: expected (h, w) or (h, w, 3)")
    h, w = a.shape[:2]
    c = 1 if a.ndim == 2 else 3
    return (int(w), int(h), c, np.ascontiguousarray(a, dtype="<f4").tobytes(), encoding == "linear")


def target(spec: str) -> np.ndarray:
    """A built-in target (``"letter:F@32"``, ``"siemens:36"``, ``"text:HI@64"``, …, as
    ``display.image`` takes them) as a float32 array (h, w) of display code values in [0, 1];
    pass it back with ``encoding="display"``."""
    w, h, b = _native.target(str(spec))
    return _f32(b, (h, w))


def _toml_key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "-_" for c in k) else json.dumps(k)


def _toml_inline(v: Any) -> str:
    if isinstance(v, Mapping):
        return "{" + ", ".join(f"{_toml_key(str(k))} = {_toml_inline(x)}" for k, x in v.items() if x is not None) + "}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_inline(x) for x in v) + "]"
    if isinstance(v, (float, np.floating)) and not np.isfinite(v):
        return "nan" if np.isnan(v) else ("inf" if v > 0 else "-inf")
    return _toml_value(v)


def _is_table_list(v: Any) -> bool:
    return isinstance(v, (list, tuple)) and len(v) > 0 and all(isinstance(x, Mapping) for x in v)


def _toml_table(d: Mapping[str, Any], prefix: str, out: list[str]) -> None:
    """Appends table ``d`` (named ``prefix``) as TOML lines: its plain keys, then its
    sub-tables and arrays of tables; None values are left out (TOML has no null)."""
    for k, v in d.items():
        if v is None or isinstance(v, Mapping) or _is_table_list(v):
            continue
        out.append(f"{_toml_key(str(k))} = {_toml_inline(v)}")
    for k, v in d.items():
        name = f"{prefix}.{_toml_key(str(k))}" if prefix else _toml_key(str(k))
        if isinstance(v, Mapping):
            out.append(f"\n[{name}]")
            _toml_table(v, name, out)
        elif _is_table_list(v):
            for item in v:
                out.append(f"\n[[{name}]]")
                _toml_table(item, name, out)


def to_toml(d: Mapping[str, Any]) -> str:
    """A scene dict (as :meth:`Scene.to_dict` gives) as TOML text a scene file holds."""
    out: list[str] = []
    _toml_table(d, "", out)
    return "\n".join(out).lstrip("\n") + "\n"


def scenes() -> list[str]:
    """The names of the scenes shipped with stscam (``scenes/NAME.toml`` in the repository,
    built into the package): ``Scene("gesture")`` or ``Scene.named("gesture")`` loads one."""
    return [n for n, _ in _native.shipped_scenes()]


class Scene:
    """A scene: the embedded paper scene (``path=None``), a TOML file merged over it, or a
    shipped scene by name (``"gesture"``, see :func:`scenes`), with ``overrides`` (a dict of
    ``--set`` keys to values, e.g. ``{"sensor.crop_px": [96, 96], "display.image":
    "letter:F@32"}``) and optionally an ``image`` held in memory in place of
    ``display.image`` (numpy (h, w) or (h, w, 3), with ``encoding="linear"`` or
    ``"display"``). :meth:`from_dict` makes one from a dict with every key, including the
    ``object`` and ``light`` lists. Checked on construction (``ValueError``)."""

    def __init__(self, path: Optional[str | os.PathLike] = None,
                 overrides: Optional[Mapping[str, Any]] = None, image: Any = None,
                 encoding: Optional[str] = None, _text: Optional[tuple[str, str, str]] = None):
        self.path: Optional[str] = None if path is None else os.fspath(path)
        shipped = dict(_native.shipped_scenes())
        if (_text is None and self.path is not None and self.path in shipped
                and not os.path.exists(self.path)):
            _text = (shipped[self.path], f"scenes/{self.path}.toml", ".")
        self._text = _text
        self.overrides: dict[str, Any] = dict(overrides or {})
        self._sets = [f"{k}={_toml_value(v)}" for k, v in self.overrides.items()]
        self._img = None if image is None else _image_arg(image, encoding, "display.image")
        #: The target held in memory (float32 (h, w) or (h, w, 3)) replacing ``display.image``,
        #: or None; ``encoding`` says what its values are.
        self.image: Optional[np.ndarray] = None
        self.encoding: Optional[str] = encoding if image is not None else None
        if self._img is not None:
            w, h, c, b, _ = self._img
            self.image = _f32(b, (h, w) if c == 1 else (h, w, 3))
        self._arg = (self.path, self._sets, self._img, self._text)
        self._json = _native.scene_json(self._arg)

    @classmethod
    def named(cls, name: str, overrides: Optional[Mapping[str, Any]] = None) -> "Scene":
        """A shipped scene by name (see :func:`scenes`)."""
        shipped = dict(_native.shipped_scenes())
        if name not in shipped:
            raise ValueError(f"scene {name!r}: not a shipped scene; shipped: {', '.join(shipped)}")
        return cls(name, overrides, _text=(shipped[name], f"scenes/{name}.toml", "."))

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], overrides: Optional[Mapping[str, Any]] = None,
                  base_dir: str | os.PathLike = ".", image: Any = None,
                  encoding: Optional[str] = None) -> "Scene":
        """A scene from a dict of sections, as a scene file holds them (every key, including
        the ``object`` and ``light`` lists of tables; missing keys keep the paper scene's
        values): the inverse of :meth:`to_dict`. Relative asset paths resolve against
        ``base_dir``."""
        if not isinstance(d, Mapping):
            raise ValueError(f"scene: expected a dict, got {type(d).__name__}")
        return cls(None, overrides, image=image, encoding=encoding,
                   _text=(to_toml(d), "<dict>", os.fspath(base_dir)))

    def with_image(self, image: Any, encoding: str) -> "Scene":
        """This scene showing ``image`` (numpy (h, w) or (h, w, 3); ``encoding="linear"`` or
        ``"display"``) on the display instead of ``display.image``; kept in memory."""
        return Scene(self.path, self.overrides, image=image, encoding=encoding, _text=self._text)

    @property
    def sets(self) -> list[str]:
        """The overrides as the CLI's ``--set KEY=VALUE`` arguments."""
        return list(self._sets)

    def to_dict(self) -> dict:
        """The full scene after overrides (as ``capture.json``'s ``scene``)."""
        return json.loads(self._json)

    def coverage_warning(self) -> Optional[str]:
        """The CLI's warning when part of the object has no strong replica inside the crop
        (``stscam matrix`` prints it), or None when every object row and column is seen."""
        return _native.coverage(self._arg)

    def __repr__(self) -> str:
        img = "" if self.image is None else f", image=<{self.image.shape} {self.encoding}>"
        return f"Scene(path={self.path!r}, overrides={self.overrides!r}{img})"


def _warn_coverage(w: Optional[str]) -> None:
    if w:
        warnings.warn(w, UserWarning, stacklevel=3)


def _scene(scene: Optional[Scene]) -> Scene:
    if scene is None:
        return Scene()
    if not isinstance(scene, Scene):
        raise ValueError(f"scene: expected stscam.Scene, got {type(scene).__name__}")
    return scene


def _f32(b: bytes, shape) -> np.ndarray:
    return np.frombuffer(b, dtype="<f4").reshape(shape).astype(np.float32, copy=True)


def _image(b: bytes, nch: int, h: int, w: int) -> np.ndarray:
    return _f32(b, (h, w) if nch == 1 else (nch, h, w))


def _csr(d: dict) -> scipy.sparse.csr_matrix:
    rows, cols = d["rows"], d["cols"]
    data = np.frombuffer(d["data"], dtype="<f4").astype(np.float32)
    nnz = data.size
    # The index type of H.npz: int32 while nnz and the column count fit (scipy's own rule).
    idx = np.int32 if max(nnz, cols) <= np.iinfo(np.int32).max else np.int64
    indptr = np.frombuffer(d["indptr"], dtype="<u8").astype(idx)
    indices = np.frombuffer(d["indices"], dtype="<u4").astype(idx)
    return scipy.sparse.csr_matrix((data, indices, indptr), shape=(rows, cols))


@dataclass
class Frontal:
    """Ground truth of a 3-D scene: what an ideal pinhole at the screen sees."""
    image: np.ndarray  #: float32 [h, w] (mono) or [c, h, w], as ``frontal.exr``
    depth: np.ndarray  #: float32 [h, w], mm from the plate along -z (inf: nothing), ``depth.exr``
    mask: np.ndarray   #: uint16 [h, w]: object index + 1, 65535 the display, 0 nothing
    channels: list[str] = field(default_factory=list)  #: as ``frontal.exr``: sensor, X,Y,Z or R,G,B
    space: str = "sensor"  #: ``"sensor"``, ``"xyz"`` or ``"linear-srgb"`` (``frontal_space``)


@dataclass
class Render:
    """What :func:`render` returns."""
    image: np.ndarray  #: float32 [h, w] (mono) or [c, h, w] (colour): ``capture.exr``'s values
    channels: list[str]  #: channel names (``Y`` or ``R``, ``G``, ``B``)
    stats: dict  #: path counters, as ``capture.json``'s ``stats``
    render_time_s: float
    spectral: Optional[np.ndarray] = None  #: float32 [bins, h, w] with ``spectral=True``
    spectral_bins_nm: list[float] = field(default_factory=list)
    frontal_result: Optional[Frontal] = None

    @property
    def frontal(self) -> Optional[np.ndarray]:
        """The frontal image (3-D scenes), else None."""
        return None if self.frontal_result is None else self.frontal_result.image

    @property
    def depth(self) -> Optional[np.ndarray]:
        """Depth in mm (3-D scenes), else None."""
        return None if self.frontal_result is None else self.frontal_result.depth

    @property
    def mask(self) -> Optional[np.ndarray]:
        """Object mask (3-D scenes), else None."""
        return None if self.frontal_result is None else self.frontal_result.mask


def _frontal_px(frontal_px: Any) -> Optional[tuple[int, int]]:
    """``frontal_px`` as the CLI's ``--frontal-px N|WxH``: one number N (N x N), a string
    ``"N"`` or ``"WxH"``, or named ``{"h": H, "w": W}``; as (w, h)."""
    if frontal_px is None:
        return None
    if isinstance(frontal_px, str):
        parts = frontal_px.lower().split("x")
        try:
            vals = [int(p) for p in parts]
        except ValueError:
            raise ValueError(f"--frontal-px {frontal_px}: expected N or WxH (1..=8192 each)") from None
        if len(vals) == 1:
            vals = vals * 2
        if len(vals) != 2:
            raise ValueError(f"--frontal-px {frontal_px}: expected N or WxH (1..=8192 each)")
        w, h = vals
    elif isinstance(frontal_px, Mapping):
        w, h = frontal_px["w"], frontal_px["h"]
    elif isinstance(frontal_px, (int, np.integer)):
        w = h = frontal_px
    else:
        w, h = frontal_px
    w = _uint(w, "--frontal-px <N|WxH>", 8192, 1)
    h = _uint(h, "--frontal-px <N|WxH>", 8192, 1)
    return (w, h)


def _check_noise(noise: Optional[str]) -> None:
    if noise not in (None, "none", "sensor"):
        raise ValueError(f"noise {noise!r}: expected None, \"none\" or \"sensor\"")


def _camera_table(camera_table: Any, table_spp: Any, table_reps: Any):
    if camera_table is None:
        return None
    return (os.fspath(camera_table), _uint(table_spp, "table_spp", _U32, 1),
            _uint(table_reps, "table_reps", _U32, 1))


def render(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
           threads: Optional[int] = None, sampler: str = "lattice", spectral: bool = False,
           frontal_px: Any = None, user_side: str = "auto", target: Any = None,
           encoding: Optional[str] = None, noise: Optional[str] = None,
           white_peak: Optional[float] = None, frontal_space: str = "sensor",
           progress: Optional[Callable[[int, int, str], Any]] = None,
           camera_table: Optional[str | os.PathLike] = None, table_spp: int = 1024,
           table_reps: int = 32, frontal_spp: Optional[int] = None,
           adaptive: bool = False) -> Render:
    """Renders the sensor crop, as ``stscam render``: same ``spp``, ``seed``, ``sampler``
    and ``user_side`` give the values of ``capture.exr`` (for any ``threads``); ``sampler`` is
    ``"lattice"`` (default: a Korobov rule searched for ``spp`` where a good one exists, else
    the R5 sequence), ``"independent"`` or ``"sobol"``; ``user_side`` (3-D scenes) is ``"auto"`` (default: ``"resampled"``,
    or ``"padded"`` in scenes with emissive meshes), ``"resampled"`` (a pixel's branches share
    about one user-side path per camera sample, drawn per replica in proportion to their
    weight), ``"padded"`` (every branch traced, the first vertex's light and BSDF samples
    stratified over a pixel's samples; independent numbers with ``sampler="independent"``),
    as ``stscam render --user-side``. ``frontal_px`` is N, ``"N"``, ``"WxH"`` or
    ``(w, h)`` as ``--frontal-px``. ``target`` (a numpy array (h, w) or (h, w, 3) with
    ``encoding="linear"`` or ``"display"``) is shown instead of the scene's image.
    ``noise="sensor"`` passes the capture through the sensor model (:func:`sensor_noise` with
    ``seed`` and ``white_peak``). The CLI's limits (``--spp``, ``--threads``, memory) are checked
    before any work: ValueError with its message. ``frontal_space`` (3-D scenes) is
    ``"sensor"`` (default: the capture's response), ``"xyz"`` (CIE 1931 XYZ, Y = 1 for a flat
    radiance at display white) or ``"linear-srgb"`` (Rec. 709, D65), as ``--frontal-space``.
    ``camera_table`` (a cache directory) takes the camera side from the design's table there,
    drawn with ``table_spp`` camera samples and ``table_reps`` exit rays per pixel on first use
    and read by every later call with the same design, crop and seed, as ``stscam render
    --camera-table``: a 3-D scene then traces ``spp`` user-side paths per pixel from the table's
    exit rays; a display-only scene's table is H at ``table_spp``, and the capture H·f + offset.
    ``frontal_spp`` (3-D scenes; default ``spp``): samples per pixel of the frontal image, as
    ``--frontal-spp``. ``adaptive=True`` shares the samples out by noise, as ``--adaptive``:
    ``spp`` (at least 16) is then the mean per pixel, a pilot included, and
    ``stats["sample_counts"]`` records the counts."""
    s = _scene(scene)
    _check_noise(noise)
    if target is not None:
        s = s.with_image(target, encoding)
    d = _native.render(s._arg, _uint(spp, "--spp <SPP>", _U32), _uint(seed, "--seed <SEED>", _U64),
                       _threads(threads), sampler, bool(spectral), _frontal_px(frontal_px),
                       user_side, [], str(frontal_space), _progress(progress),
                       _camera_table(camera_table, table_spp, table_reps),
                       None if frontal_spp is None else _uint(frontal_spp, "--frontal-spp <N>", _U32),
                       bool(adaptive))
    w, h, names = d["width"], d["height"], d["channels"]
    nb = len(d["spectral_bins_nm"])
    out = Render(
        image=_image(d["image"], len(names), h, w),
        channels=list(names),
        stats=json.loads(d["stats"]),
        render_time_s=d["render_time_s"],
        spectral=_f32(d["spectral"], (nb, h, w)) if nb else None,
        spectral_bins_nm=list(d["spectral_bins_nm"]),
    )
    f = d.get("frontal")
    if f is not None:
        fw, fh = f["width"], f["height"]
        out.frontal_result = Frontal(
            image=_image(f["image"], len(f["channels"]), fh, fw),
            depth=_f32(f["depth"], (fh, fw)),
            mask=np.frombuffer(f["mask"], dtype="<u2").reshape(fh, fw).astype(np.uint16),
            channels=list(f["channels"]),
            space=f["space"],
        )
    if noise == "sensor":
        out.image = sensor_noise(s, out.image, seed=seed, white_peak=white_peak).reshape(out.image.shape)
    return out


def render_batch(scene: Optional[Scene], targets: Any, encoding: Optional[str] = None,
                 spp: int = 64, seed: int = 1, threads: Optional[int] = None,
                 sampler: str = "lattice", user_side: str = "auto",
                 noise: Optional[str] = None, white_peak: Optional[float] = None,
                 progress: Optional[Callable[[int, int, str], Any]] = None,
                 camera_table: Optional[str | os.PathLike] = None, table_spp: int = 1024,
                 table_reps: int = 32, adaptive: bool = False) -> np.ndarray:
    """Renders each of ``targets`` (an array (n, h, w) or (n, h, w, 3), or a sequence of
    (h, w) arrays) on the scene's display in one call, the scene built once: float32
    (n, h, w) or (n, c, h, w), image i equal to ``render(scene, target=targets[i], ...).image``
    (same ``seed`` for each). ``noise="sensor"`` gives each its noise with seed ``seed + i``.
    With ``camera_table`` (as :func:`render`) H is read (or built) once and each target's
    image is H·f + offset. ``adaptive=True`` (as :func:`render`) gives each target its own
    pilot and counts."""
    s = _scene(scene)
    _check_noise(noise)
    # Each target's capture (float32, up to three channels) counts against the job's memory
    # too: refused here, before the targets are converted.
    crop = json.loads(s._json)["sensor"]["crop_px"]
    _check_arrays(targets, "targets", extra_bytes_each=int(crop[0]) * int(crop[1]) * 3 * 4)
    args = [_image_arg(t, encoding, f"targets[{i}]") for i, t in enumerate(targets)]
    if not args:
        raise ValueError("targets: no targets")
    d = _native.render(s._arg, _uint(spp, "--spp <SPP>", _U32), _uint(seed, "--seed <SEED>", _U64),
                       _threads(threads), sampler, False, None, user_side, args, "sensor",
                       _progress(progress), _camera_table(camera_table, table_spp, table_reps),
                       None, bool(adaptive))
    w, h, names = d["width"], d["height"], d["channels"]
    imgs = [_image(d["image"], len(names), h, w)] + [_image(b, len(names), h, w) for b in d["batch_rest"]]
    out = np.stack(imgs)
    if noise == "sensor":
        for i in range(len(out)):
            si = s.with_image(targets[i], encoding)
            out[i] = sensor_noise(si, out[i], seed=int(seed) + i, white_peak=white_peak).reshape(out[i].shape)
    return out


def _white_peak(s: Scene) -> float:
    """The default exposure of :func:`sensor_noise`: the brightest value of a 16-spp render
    of the scene with a white target of its object size."""
    cols, rows = info(s)["object_coverage"]["object_px"]
    white = np.ones((int(rows), int(cols)), dtype=np.float32)
    return float(render(s.with_image(white, "linear"), spp=16, seed=1).image.max())


def sensor_noise(scene: Optional[Scene], clean: Any, seed: int = 1,
                 white_peak: Optional[float] = None) -> np.ndarray:
    """The scene's sensor model (``[noise]``: shot, read and dark noise, bit depth,
    saturation, exposure, and the EMVA 1288 fixed patterns when the scene sets them: PRNU,
    DSNU, dark current, hot pixels, drawn per value index from ``noise.sensor_seed`` and the
    same for every ``seed``) applied to a clean capture (any shape, capture units): float32,
    same shape, in capture units with the mean dark offset removed, exactly as ``stscam
    dataset`` stores a noisy capture (pixel i draws from ``NoiseRng([seed, 0x4E4F4953, i])``;
    a dataset sample's seed is ``metadata.jsonl``'s ``seed``). The exposure is fixed by
    ``white_peak``, the brightest value of the all-white capture (a dataset's
    ``dataset.json`` → ``exposure.white_peak``); default: from a 16-spp render of the scene
    with a white target of the scene's object size."""
    s = _scene(scene)
    a = np.asarray(clean, dtype=np.float64)
    if white_peak is None:
        white_peak = _white_peak(s)
    b = _native.sensor_noise(s._arg, np.ascontiguousarray(a, dtype="<f8").tobytes(),
                             _uint(seed, "--seed <SEED>", _U64), float(white_peak))
    return np.frombuffer(b, dtype="<f4").reshape(a.shape).astype(np.float32)


def matrix(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
           depth_mm: Optional[float] = None,
           threads: Optional[int] = None,
           progress: Optional[Callable[[int, int, str], Any]] = None) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
    """The system matrix H (rows: crop pixels, channel-major; columns: object pixels) and the
    offset (capture of an all-black object), equal to ``stscam matrix``'s ``H.npz`` and
    ``offset.npy``. ``depth_mm`` moves the object plane, keeping the focus."""
    s = _scene(scene)
    d = _native.matrix(s._arg, _uint(spp, "--spp <SPP>", _U32), _uint(seed, "--seed <SEED>", _U64),
                       None if depth_mm is None else float(depth_mm), _threads(threads),
                       _progress(progress))
    _warn_coverage(d["warning"])
    h = _csr(d)
    return h, np.frombuffer(d["offset"], dtype="<f4").astype(np.float32)


def matrix_stack(scene: Optional[Scene] = None, depth_mm="300:650:8", spp: int = 64,
                 seed: int = 1, threads: Optional[int] = None,
                 progress: Optional[Callable[[int, int, str], Any]] = None
                 ) -> list[tuple[float, scipy.sparse.csr_matrix, np.ndarray]]:
    """A depth stack in one pass, as ``stscam matrix --depth-mm SPEC``: ``[(depth_mm, H,
    offset), ...]`` sorted by depth, each H and offset equal to that run's ``H_<D>mm.npz``
    and ``offset_<D>mm.npy`` (and to ``matrix(scene, depth_mm=D)``). ``depth_mm`` is a
    sequence of depths in mm or the CLI's ``"START:STOP:STEPS"``. The block matrix of the
    layered model is ``scipy.sparse.hstack([H for _, H, _ in stack], format="csr")``."""
    s = _scene(scene)
    if isinstance(depth_mm, str):
        spec = depth_mm
    else:
        try:
            spec = ",".join(repr(float(d)) for d in depth_mm)
        except (TypeError, ValueError):
            raise ValueError(f"--depth-mm {depth_mm!r}: expected depths in mm or START:STOP:STEPS") from None
    out = []
    for d in _native.matrix_stack(s._arg, _uint(spp, "--spp <SPP>", _U32),
                                  _uint(seed, "--seed <SEED>", _U64), spec, _threads(threads),
                                  _progress(progress)):
        out.append((float(d["depth_mm"]), _csr(d), np.frombuffer(d["offset"], dtype="<f4").astype(np.float32)))
    return out


def info(scene: Optional[Scene] = None) -> dict:
    """Design summary, equal to ``stscam info --json``."""
    s = _scene(scene)
    return json.loads(_native.info(s._arg))


def probe(scene: Optional[Scene] = None, pixel: tuple[int, int] = (0, 0)) -> dict:
    """The chief ray of pixel ``(col, row)``, equal to ``stscam probe --pixel COL,ROW --json``."""
    s = _scene(scene)
    try:
        col, row = (operator.index(v) for v in pixel)
    except (TypeError, ValueError):
        raise ValueError(f"--pixel {pixel!r}: expected COL,ROW with non-negative integers") from None
    if not (0 <= col <= _U64 and 0 <= row <= _U64):
        raise ValueError(f"--pixel {col},{row}: expected COL,ROW with non-negative integers")
    return json.loads(_native.probe(s._arg, col, row))


def reconstruct(H, capture, method: str = "admm-tv", iters: Optional[int] = None,
                tau: Optional[float] = None, offset=None, tv: str = "iso",
                object_shape: Optional[tuple[int, int]] = None,
                threads: Optional[int] = None, return_info: bool = False,
                regularisation: str = "discrepancy", sensor: Optional[Scene] = None,
                white_peak: Optional[float] = None):
    """Reconstructs the object from ``capture`` (any shape, flattened in H's row order) with
    CG (``method="cg"``) or ADMM-TV, as ``stscam reconstruct``. ``H`` is any scipy sparse
    matrix (stored as float32, like ``H.npz``); ``offset`` (float32, like ``offset.npy``) is
    subtracted first. ``regularisation="discrepancy"`` (the default, as the CLI and the demo)
    chooses ADMM-TV's τ and CGM's stopping iteration (at most ``iters``, default 100) from
    the noise of ``sensor``'s ``[noise]`` model (default: the default scene's) at the exposure
    ``white_peak`` (default: max(H·1 + offset)); the capture is taken as measured with the
    mean dark offset removed (:func:`sensor_noise`, datasets). ``regularisation="fixed"``
    uses ``tau`` (relative to ‖Hᵀg‖∞, default 0.001) and ``iters`` (CG: 30) as given.
    Returns the object as a float64 array [h, w] (``object_shape=(h, w)``, numpy's order;
    default: square), or [3, h, w] for a colour H (3·h·w columns, blocks R, G, B: CGM on the
    whole vector, ADMM-TV with TV per plane, as the CLI), and with ``return_info=True`` also
    the solver's report (``recon.json``'s ``solver``)."""
    rule = _rule_args(regularisation, tau, sensor, white_peak)
    if not scipy.sparse.issparse(H):
        raise ValueError(f"H: expected a scipy sparse matrix, got {type(H).__name__}")
    h = scipy.sparse.csr_matrix(H, dtype=np.float32, copy=True)
    h.sum_duplicates()
    h.sort_indices()
    rows, cols = h.shape
    hh, w = _object_shape_of(cols, object_shape)
    planes = _planes_of(cols, (hh, w))
    g = np.ascontiguousarray(np.asarray(capture, dtype=np.float64).reshape(-1))
    off = None if offset is None else np.ascontiguousarray(
        np.asarray(offset, dtype=np.float32).reshape(-1)).astype("<f4").tobytes()
    f, solver = _native.reconstruct(
        rows, cols, h.indptr.astype("<i8").tobytes(), h.indices.astype("<i8").tobytes(),
        h.data.astype("<f4").tobytes(), (w, hh), g.astype("<f8").tobytes(), off, method,
        None if iters is None else _uint(iters, "--iters <ITERS>", _U64),
        0.001 if tau is None else float(tau), tv, _threads(threads), *rule, planes)
    shape = (hh, w) if planes == 1 else (3, hh, w)
    obj = np.frombuffer(f, dtype="<f8").reshape(shape).astype(np.float64)
    return (obj, json.loads(solver)) if return_info else obj


def _rule_args(regularisation: str, tau: Optional[float], sensor: Any,
               white_peak: Optional[float]) -> tuple[Any, Optional[float]]:
    """The native sensor arguments (scene, white peak) of a ``regularisation`` choice, or
    (None, None) for fixed parameters; the CLI's refusals as ``ValueError``."""
    if regularisation == "fixed":
        for name, v in (("sensor", sensor), ("white_peak", white_peak)):
            if v is not None:
                raise ValueError(f"{name}: sets the discrepancy principle's sensor model; "
                                 "regularisation=\"fixed\" does not use it")
        return None, None
    if regularisation != "discrepancy":
        raise ValueError(f"regularisation {regularisation!r}: expected \"discrepancy\" or \"fixed\"")
    if tau is not None:
        raise ValueError("tau: sets tau of regularisation=\"fixed\"; the default, the discrepancy "
                         "principle, chooses tau from the sensor noise")
    if white_peak is not None:
        white_peak = float(white_peak)
    return _scene(sensor)._arg, white_peak


def reconstruct_stack(stack, capture, method: str = "joint", iters: Optional[int] = None,
                      tau: Optional[float] = None, mu: Optional[float] = None, offset=None,
                      tv: str = "iso", object_shape: Optional[tuple[int, int]] = None,
                      threads: Optional[int] = None):
    """Reconstruction with a depth stack (``[(depth_mm, H, offset), ...]`` as
    :func:`matrix_stack` returns it), as ``stscam reconstruct --matrix H_stack.npz``:
    ``method="joint"`` reconstructs every plane at once (joint ADMM-TV with a group-sparsity
    prior across depth, weight ``mu`` relative to ‖Hᵀg‖∞, default 1e-5; the capture minus
    ``offset``, default the sum of the depths' offsets); ``method="depth"`` estimates the depth
    of one planar object (each depth's own offset subtracted) and reconstructs it there.
    Returns ``{"planes": {depth_mm: object [h, w]}, "estimate": dict or None, "solver": dict}``."""
    blocks = []
    for item in stack:
        try:
            d, H, off = item
        except (TypeError, ValueError):
            raise ValueError("stack: expected (depth_mm, H, offset) items as matrix_stack returns") from None
        if not scipy.sparse.issparse(H):
            raise ValueError(f"H at {d} mm: expected a scipy sparse matrix, got {type(H).__name__}")
        h = scipy.sparse.csr_matrix(H, dtype=np.float32, copy=True)
        h.sum_duplicates()
        h.sort_indices()
        o = None if off is None else np.ascontiguousarray(
            np.asarray(off, dtype=np.float32).reshape(-1)).astype("<f4").tobytes()
        blocks.append((float(d), h.shape[0], h.shape[1], h.indptr.astype("<i8").tobytes(),
                       h.indices.astype("<i8").tobytes(), h.data.astype("<f4").tobytes(), o))
    if not blocks:
        raise ValueError("stack: no depths")
    cols = blocks[0][2]
    if object_shape is None:
        side = int(round(cols ** 0.5))
        if side * side != cols:
            raise ValueError(f"{cols} columns are not a square object; pass object_shape=(h, w)")
        object_shape = (side, side)
    hh, w = (int(v) for v in object_shape)
    g = np.ascontiguousarray(np.asarray(capture, dtype=np.float64).reshape(-1))
    joint = None if offset is None else np.ascontiguousarray(
        np.asarray(offset, dtype=np.float32).reshape(-1)).astype("<f4").tobytes()
    planes, estimate, solver = _native.reconstruct_stack(
        blocks, (w, hh), g.astype("<f8").tobytes(), joint, method,
        None if iters is None else _uint(iters, "--iters <ITERS>", _U64),
        0.001 if tau is None else float(tau), 1e-5 if mu is None else float(mu), tv,
        _threads(threads))
    return {
        "planes": {d: np.frombuffer(b, dtype="<f8").reshape(hh, w).astype(np.float64) for d, b in planes},
        "estimate": None if estimate is None else json.loads(estimate),
        "solver": json.loads(solver),
    }


def calibrate(scene: Optional[Scene] = None, spp: int = 64, seed: int = 1,
              matrix: Optional[str | os.PathLike] = None,
              object_shape: Optional[tuple[int, int]] = None, noise: str = "sensor",
              dark_frame: bool = False, render: bool = False, threshold_sigma: float = 5.0,
              threads: Optional[int] = None,
              progress: Optional[Callable[[int, int, str], Any]] = None) -> tuple[scipy.sparse.csr_matrix, dict]:
    """The paper's Hadamard calibration, simulated (``stscam calibrate``): returns H_est (as
    ``H_est.npz``) and the report (``calibration.json``'s ``report``; for a colour display,
    calibrated per primary as ``stscam demo --colour`` does, a dict of the reports of ``"R"``,
    ``"G"`` and ``"B"``, its ``report_per_primary``). ``matrix`` is an ``H.npz`` path
    (default: H computed from the scene) and ``object_shape`` its object (h, w) where no
    ``H.json`` beside it says; a scene holding an array target calibrates that."""
    if noise not in ("sensor", "none"):
        raise ValueError(f"noise {noise!r}: expected \"sensor\" or \"none\"")
    s = _scene(scene)
    d = _native.calibrate(s._arg, _uint(spp, "--spp <SPP>", _U32), _uint(seed, "--seed <SEED>", _U64),
                          None if matrix is None else os.fspath(matrix),
                          None if object_shape is None else (int(object_shape[1]), int(object_shape[0])),
                          noise == "sensor", bool(dark_frame), bool(render),
                          float(threshold_sigma), _threads(threads), _progress(progress))
    return _csr(d), json.loads(d["report"])


def sweep(scene: Optional[Scene] = None, vary: Sequence[str] | Mapping[str, tuple] = (),
          fov_fraction: float = 0.1, psnr: Optional[str] = None, psnr_spp: int = 64,
          threads: Optional[int] = None,
          progress: Optional[Callable[[int, int, str], Any]] = None) -> list[dict]:
    """A design sweep, equal to ``stscam sweep --json``: ``vary`` is a list of
    ``KEY=START:STOP:STEPS`` or a dict ``{KEY: (start, stop, steps)}``; one dict per grid point."""
    if isinstance(vary, Mapping):
        vary = [f"{k}={a}:{b}:{n}" for k, (a, b, n) in vary.items()]
    s = _scene(scene)
    return json.loads(_native.sweep(s._arg, list(vary), float(fov_fraction), psnr,
                                    _uint(psnr_spp, "--psnr-spp <PSNR_SPP>", _U32), _threads(threads),
                                    _progress(progress)))


def _csv_floats(v: Any, flag: str) -> Optional[str]:
    """A list of numbers (or one number) as the CLI's comma-separated ``flag`` value."""
    if v is None:
        return None
    if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
        v = [v]
    try:
        return ",".join(repr(float(x)) for x in v)
    except (TypeError, ValueError):
        raise ValueError(f"{flag}: expected a number or a list of numbers, got {v!r}") from None


def evaluate(scene: Optional[Scene] = None, metrics: Sequence[str] | str = ("psnr_db",),
             targets: Optional[Sequence[Any]] = None, encoding: Optional[str] = None,
             depth_mm: Any = None, object_px: int = 32, binning: int = 2, spp: int = 8,
             replicates: int = 2, white_peak: Optional[float] = None,
             draw: Sequence[str] = (), draws: int = 64, require: Sequence[str] = (),
             seed: int = 1, threads: Optional[int] = None,
             progress: Optional[Callable[[int, int, str], Any]] = None) -> dict[str, float]:
    """One design's metrics, equal to ``stscam evaluate --metrics ... --json``: a dict of
    metric name to value, with ``<name>_error`` where the metric carries Monte Carlo error (an
    undefined metric, e.g. the band coverage of a monochrome design, is NaN).

    ``targets`` (reconstruction metrics) mixes built-in specs without size (``"letter:A"``),
    PNG/EXR paths and numpy arrays ((h, w) or (h, w, 3); their ``encoding`` is ``"linear"``
    or ``"display"``, as for :func:`render`'s ``target``); default the demo's four.
    ``depth_mm`` is one object depth or a list (default the scene's display distance).
    ``white_peak`` fixes the exposure (``optimize`` holds its base design's); ``draw``
    (``KEY=normal(M,SD)``), ``draws`` and ``require`` (``METRIC>=V``) give the yield and
    ``_q05`` quantiles. Defaults are the CLI's (docs/design-studies.md)."""
    s = _scene(scene)
    if isinstance(metrics, str):
        metrics = [metrics]
    names = ",".join(str(m) for m in metrics)
    specs: list[str] = []
    images = []
    for i, t in enumerate(targets or ()):
        if isinstance(t, (str, os.PathLike)):
            specs.append(os.fspath(t))
        else:
            images.append((f"targets[{i}]", _image_arg(t, encoding, f"targets[{i}]")))
    if targets is not None and not specs and not images:
        raise ValueError("targets: give at least one target (or None for the demo's four)")
    for t in specs:
        if "," in t:
            raise ValueError(f"targets: {t!r} contains a comma")
    out, warns = _native.evaluate(
        s._arg, names, _uint(object_px, "--object-px <OBJECT_PX>", _U32),
        _uint(binning, "--binning <BINNING>", _U32), _uint(spp, "--spp <SPP>", _U32),
        _uint(replicates, "--replicates <REPLICATES>", _U64),
        ",".join(specs) if specs else None, images, _csv_floats(depth_mm, "--depth-mm"),
        None if white_peak is None else float(white_peak), [str(d) for d in draw],
        _uint(draws, "--draws <DRAWS>", _U64), [str(r) for r in require],
        _uint(seed, "--seed <SEED>", _U64), _threads(threads), _progress(progress))
    for w in warns:
        _warn_coverage(w)
    return {k: (float("nan") if v is None else float(v)) for k, v in json.loads(out).items()}


class Optimization:
    """What :func:`optimize` found (the files of ``out`` read back): ``history`` (one dict per
    evaluation: ``index``, ``step``, ``params`` by parameter name, ``metrics``,
    ``violations``, ``feasible``, ``seconds``), ``best`` (the index of the best feasible
    design, or None for an infeasible study), ``best_scene`` (its :class:`Scene`, from
    ``best.toml``, or None), ``pareto`` (indices of the Pareto front), ``summary`` (the
    ``summary.json`` dict) and ``out`` (the folder of the files, or None when they were not
    kept)."""

    def __init__(self, history: list[dict], summary: dict, best_scene: Optional[Scene],
                 out: Optional[str]):
        self.history = history
        self.summary = summary
        self.best: Optional[int] = summary.get("best")
        self.pareto: list[int] = list(summary.get("pareto") or [])
        self.best_scene = best_scene
        self.out = out

    def params(self) -> np.ndarray:
        """The parameters of every evaluation, (evaluations, parameters), float64."""
        return np.array([list(h["params"].values()) for h in self.history], dtype=np.float64)

    def metric(self, name: str) -> np.ndarray:
        """One metric of every evaluation (NaN where it was not computed), float64."""
        return np.array([h["metrics"].get(name, float("nan")) for h in self.history],
                        dtype=np.float64)

    def __repr__(self) -> str:
        return (f"Optimization({len(self.history)} evaluations, best={self.best}, "
                f"pareto={self.pareto})")


def optimize(study: str | os.PathLike | Mapping[str, Any], budget: int = 40, seed: int = 1,
             out: Optional[str | os.PathLike] = None, resume: bool = False,
             skip_final: bool = False, threads: Optional[int] = None,
             progress: Optional[Callable[[int, int, str], Any]] = None,
             base_dir: str | os.PathLike = ".") -> Optimization:
    """Optimises a design study (``stscam optimize STUDY --budget N --seed S --out OUT``):
    ``study`` is a study file or a dict with the file's tables (``parameter``, ``objective``,
    ``constraint`` lists, ``search``, ``final``, ``optimizer``; relative paths resolve
    against ``base_dir``). The files are the CLI's, written into ``out`` (kept) or into a
    temporary folder that is removed after they are read back (``out=None``). ``progress``
    counts evaluations."""
    import tempfile
    path, text = None, None
    if isinstance(study, Mapping):
        text = (to_toml(study), "<dict>", os.fspath(base_dir))
        name_dir = os.fspath(base_dir)
    elif isinstance(study, (str, os.PathLike)):
        path = os.fspath(study)
        name_dir = os.path.dirname(os.path.abspath(path))
    else:
        raise ValueError(f"study: expected a path or a dict, got {type(study).__name__}")
    tmp = tempfile.TemporaryDirectory(prefix="stscam-optimize-") if out is None else None
    try:
        folder = tmp.name if tmp is not None else os.fspath(out)
        names = _native.optimize(path, text, _uint(budget, "--budget <BUDGET>", _U64),
                                 _uint(seed, "--seed <SEED>", _U64), folder, bool(resume),
                                 bool(skip_final), _threads(threads), _progress(progress))
        with open(os.path.join(folder, "summary.json"), encoding="utf-8") as f:
            summary = json.load(f)
        history = []
        with open(os.path.join(folder, "history.jsonl"), encoding="utf-8") as f:
            for line in f:
                r = json.loads(line)
                r.pop("bits", None)
                r["params"] = dict(zip(names, r["params"]))
                r["metrics"] = {k: (float("nan") if v is None else v)
                                for k, v in r["metrics"].items()}
                history.append(r)
        best_scene = None
        best = os.path.join(folder, "best.toml")
        if os.path.exists(best):
            with open(best, encoding="utf-8") as f:
                best_scene = Scene(None, _text=(f.read(), "best.toml", name_dir))
        return Optimization(history, summary, best_scene, None if tmp is not None else folder)
    finally:
        if tmp is not None:
            tmp.cleanup()


def build_dataset(recipe: str | os.PathLike, out: str | os.PathLike,
                  shard: Optional[str | tuple[int, int]] = None, resume: bool = False,
                  threads: Optional[int] = None,
                  progress: Optional[Callable[[int, int, str], Any]] = None,
                  objects: Any = None, encoding: Optional[str] = None) -> dict:
    """Builds a dataset (``stscam dataset RECIPE --out OUT [--shard I/N] [--resume]``); the
    files are byte-identical to the CLI's. Returns the run summary.

    ``objects`` (an array (n, h, w), or a sequence of (h, w) arrays, with ``encoding="linear"``
    or ``"display"`` as for :func:`render`'s ``target``) replaces the recipe's object sources:
    sample i's object is ``objects[i]`` and the recipe's ``samples`` becomes n; h = w must be
    the recipe's ``objects.size_px``. Shards, ``resume`` and merging work as for any recipe
    (the arrays are part of the recipe hash, so shards of different arrays are not merged)."""
    if isinstance(shard, tuple):
        shard = f"{shard[0]}/{shard[1]}"
    arrays = None
    if objects is not None:
        _check_arrays(objects, "objects", max_count=int(_native.MAX_SAMPLES))
        parts = [_image_arg(o, encoding, f"objects[{i}]") for i, o in enumerate(objects)]
        if not parts:
            raise ValueError("objects: no objects")
        w, h = parts[0][0], parts[0][1]
        for i, (wi, hi, c, _, _) in enumerate(parts):
            if c != 1 or (wi, hi) != (w, h) or w != h:
                raise ValueError(f"objects[{i}]: expected square (h, w) monochrome arrays of one size, "
                                 f"got {hi}x{wi}x{c} (first: {h}x{w})")
        arrays = (len(parts), w, b"".join(p[3] for p in parts), encoding == "linear")
    summary, warns = _native.build_dataset(os.fspath(recipe), os.fspath(out), shard,
                                           bool(resume), _threads(threads), _progress(progress),
                                           arrays)
    for w in warns:
        _warn_coverage(w)
    return json.loads(summary)


def merge_dataset(shards: Sequence[str | os.PathLike], out: str | os.PathLike,
                  threads: Optional[int] = None) -> dict:
    """Joins finished shards (``stscam dataset merge``)."""
    return json.loads(_native.merge_dataset([os.fspath(p) for p in shards], os.fspath(out),
                                            _threads(threads)))


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """The channels of an EXR file written by stscam, float32 [h, w] each, by name."""
    w, h, chans = _native.read_exr(os.fspath(path))
    return {name: _f32(b, (h, w)) for name, b in chans}


def write_exr(path: str | os.PathLike, channels: Mapping[str, Any]) -> None:
    """Writes float32 channels (name → array (h, w), all one size) as an EXR file the way
    stscam writes its images; ``display.image`` reads a ``Y`` (or ``R``, ``G``, ``B``) EXR as
    linear intensity."""
    arrs = {k: np.asarray(v, dtype=np.float32) for k, v in channels.items()}
    shapes = {a.shape for a in arrs.values()}
    if len(shapes) != 1 or len(next(iter(shapes))) != 2:
        raise ValueError(f"channels: expected 2-D arrays of one shape, got {sorted(shapes)}")
    h, w = next(iter(shapes))
    _native.write_exr(os.fspath(path), w, h, [(k, np.ascontiguousarray(a, "<f4").tobytes()) for k, a in arrs.items()])

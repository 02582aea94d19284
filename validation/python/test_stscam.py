"""pytest of the Python package against the CLI (run by .ci/run after `pip install .`).

Every equality is bit for bit: the CLI (the binary in $STSCAM, default target/release/stscam)
writes its files into a temporary folder in the same run and the Python call with the same
inputs must give the same float32 bits, the same sparse arrays, the same JSON, the same dataset
bytes. The error tests check that bad input raises ValueError with the CLI's one-line message.
"""
import _thread
import filecmp
import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

import stscam

ROOT = Path(__file__).resolve().parents[2]
CLI = os.environ.get("STSCAM", str(ROOT / "target" / "release" / "stscam"))
# A small scene: a 64x48 crop of the paper camera looking at a 32x32 glyph.
SETS = {"sensor.crop_px": [64, 48], "display.image": "letter:F@32"}
SPP = 4


def cli(*args, check=True):
    r = subprocess.run([CLI, *map(str, args)], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise AssertionError(f"stscam {' '.join(map(str, args))}: {r.stderr}")
    return r


def set_args(sets):
    return [a for k, v in sets.items() for a in ("--set", f"{k}={stscam._toml_value(v)}")]


def same_bits(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module")
def scene():
    return stscam.Scene(overrides=SETS)


def test_scene_to_dict_has_the_overrides(scene):
    d = scene.to_dict()
    assert d["sensor"]["crop_px"] == [64, 48]
    assert d["display"]["image"] == "letter:F@32"
    assert stscam.Scene().to_dict()["sensor"]["crop_px"] != [64, 48]


def test_render_equals_cli_capture_exr(scene, tmp_path):
    cli("render", "--out", tmp_path, "--spp", SPP, "--seed", 3, *set_args(SETS))
    exr = stscam.read_exr(tmp_path / "capture.exr")
    r = stscam.render(scene, spp=SPP, seed=3)
    assert r.image.shape == (48, 64) and r.image.dtype == np.float32
    assert same_bits(r.image, exr["Y"])
    assert r.stats == json.load(open(tmp_path / "capture.json"))["stats"]
    assert r.frontal is None and r.depth is None and r.mask is None
    # Another seed gives other numbers: the equality above can fail.
    assert not same_bits(stscam.render(scene, spp=SPP, seed=4).image, exr["Y"])


def test_render_samplers_equal_cli(scene, tmp_path):
    for sampler in ("sobol", "independent"):
        out = tmp_path / sampler
        cli("render", "--out", out, "--spp", SPP, "--sampler", sampler, *set_args(SETS))
        r = stscam.render(scene, spp=SPP, sampler=sampler)
        assert same_bits(r.image, stscam.read_exr(out / "capture.exr")["Y"])
        # Each sampler gives other numbers than the default lattice's.
        assert not same_bits(r.image, stscam.render(scene, spp=SPP).image)
    with pytest.raises(ValueError, match="sobol"):
        stscam.render(scene, spp=SPP, sampler="halton")


def test_removed_options_are_refused_with_the_remaining_names(scene):
    # `--sampler r5` and `--user-side hashed` were removed (their benchmark curves are kept in
    # validation/results/retired/); the message names what is left.
    with pytest.raises(ValueError, match='"lattice", "independent" or "sobol"'):
        stscam.render(scene, spp=4, sampler="r5")


def test_render_is_the_same_for_any_thread_count(scene):
    a = stscam.render(scene, spp=SPP, seed=5, threads=1).image
    b = stscam.render(scene, spp=SPP, seed=5, threads=2).image
    assert same_bits(a, b)


def test_colour_render_is_channel_first_and_equals_cli(tmp_path):
    sets = dict(SETS, **{"sensor.response": "rgb-bayer"})
    cli("render", "--out", tmp_path, "--spp", 2, *set_args(sets))
    exr = stscam.read_exr(tmp_path / "capture.exr")
    r = stscam.render(stscam.Scene(overrides=sets), spp=2)
    assert r.channels == ["R", "G", "B"] and r.image.shape == (3, 48, 64)
    assert same_bits(r.image, np.stack([exr[c] for c in "RGB"]))


def test_3d_scene_gives_frontal_depth_and_mask_equal_to_cli(tmp_path):
    path = ROOT / "scenes" / "gesture.toml"
    sets = {"sensor.crop_px": [24, 24], "sensor.pitch_um": 40.0}
    cli("render", path, "--out", tmp_path, "--spp", 1, "--frontal-px", "16x12", *set_args(sets))
    r = stscam.render(stscam.Scene(path, sets), spp=1, frontal_px=(16, 12))
    assert same_bits(r.image, stscam.read_exr(tmp_path / "capture.exr")["Y"])
    assert r.frontal.shape == (12, 16) and r.depth.shape == (12, 16) and r.mask.dtype == np.uint16
    assert same_bits(r.frontal, stscam.read_exr(tmp_path / "frontal.exr")["Y"])
    assert same_bits(r.depth, stscam.read_exr(tmp_path / "depth.exr")["Z"])
    assert np.isfinite(r.depth).any() and (r.mask > 0).any()


def test_frontal_space_xyz_equals_cli(tmp_path):
    path = ROOT / "scenes" / "gesture.toml"
    sets = {"sensor.crop_px": [24, 24], "sensor.pitch_um": 40.0}
    cli("render", path, "--out", tmp_path, "--spp", 1, "--frontal-space", "xyz", *set_args(sets))
    r = stscam.render(stscam.Scene(path, sets), spp=1, frontal_space="xyz")
    assert r.frontal_result.channels == ["X", "Y", "Z"] and r.frontal_result.space == "xyz"
    exr = stscam.read_exr(tmp_path / "frontal.exr")
    assert same_bits(r.frontal, np.stack([exr[c] for c in "XYZ"]))
    with pytest.raises(ValueError, match="frontal_space"):
        stscam.render(stscam.Scene(path, sets), spp=1, frontal_space="rgb")


def test_3d_user_side_modes_equal_cli_and_differ(tmp_path):
    path = ROOT / "scenes" / "gesture.toml"
    sets = {"sensor.crop_px": [24, 24], "sensor.pitch_um": 40.0}
    s = stscam.Scene(path, sets)
    images = {}
    for mode in ("resampled", "padded"):
        out = tmp_path / mode
        cli("render", path, "--out", out, "--spp", 4, "--user-side", mode, *set_args(sets))
        images[mode] = stscam.render(s, spp=4, user_side=mode).image
        assert same_bits(images[mode], stscam.read_exr(out / "capture.exr")["Y"]), mode
        assert json.load(open(out / "capture.json"))["world"]["user_side"] == mode
    # The default is the resampled user side; the two estimators draw different numbers.
    assert same_bits(stscam.render(s, spp=4).image, images["resampled"])
    assert not same_bits(images["resampled"], images["padded"])
    with pytest.raises(ValueError, match="resampled"):
        stscam.render(s, spp=4, user_side="sobol")
    with pytest.raises(ValueError, match="padded"):
        stscam.render(s, spp=4, user_side="hashed")


def test_matrix_equals_cli_npz_and_offset(scene, tmp_path):
    cli("matrix", "--out", tmp_path, "--spp", SPP, "--depth-mm", 480, *set_args(SETS))
    h_cli = scipy.sparse.load_npz(tmp_path / "H.npz")
    off_cli = np.load(tmp_path / "offset.npy")
    h, off = stscam.matrix(scene, spp=SPP, depth_mm=480)
    assert isinstance(h, scipy.sparse.csr_matrix) and h.shape == h_cli.shape == (48 * 64, 32 * 32)
    for name in ("data", "indices", "indptr"):
        assert same_bits(getattr(h, name), getattr(h_cli, name)), name
    assert same_bits(off, off_cli)
    # The default depth is another matrix.
    h2, _ = stscam.matrix(scene, spp=SPP)
    assert not (h2.nnz == h.nnz and same_bits(h2.data, h.data))


def test_matrix_stack_equals_cli_depth_files(scene, tmp_path):
    cli("matrix", "--out", tmp_path, "--spp", SPP, "--depth-mm", "400,480", *set_args(SETS))
    stack = stscam.matrix_stack(scene, depth_mm=[480, 400], spp=SPP)
    assert [d for d, _, _ in stack] == [400.0, 480.0]
    for d, h, off in stack:
        h_cli = scipy.sparse.load_npz(tmp_path / f"H_{d:g}mm.npz")
        for name in ("data", "indices", "indptr"):
            assert same_bits(getattr(h, name), getattr(h_cli, name)), (d, name)
        assert same_bits(off, np.load(tmp_path / f"offset_{d:g}mm.npy"))
    # The block matrix of the layered model is the CLI's H_stack.npz.
    block = scipy.sparse.hstack([h for _, h, _ in stack], format="csr")
    b_cli = scipy.sparse.load_npz(tmp_path / "H_stack.npz")
    assert block.shape == b_cli.shape and (block != b_cli).nnz == 0
    # A range as the CLI writes it, and the CLI's message for a bad one.
    assert [d for d, _, _ in stscam.matrix_stack(scene, depth_mm="400:480:2", spp=1)] == [400.0, 480.0]
    with pytest.raises(ValueError) as e:
        stscam.matrix_stack(scene, depth_mm="480:400:2", spp=1)
    assert str(e.value) == cli_error("matrix", "--depth-mm", "480:400:2", "--out", tmp_path / "bad")


@pytest.mark.parametrize("method", ["depth", "joint"])
def test_reconstruct_stack_equals_cli(scene, tmp_path, method):
    cli("matrix", "--out", tmp_path / "m", "--spp", SPP, "--depth-mm", "400,480", *set_args(SETS))
    sets = dict(SETS, **{"display.distance_mm": 400.0})
    cli("render", "--out", tmp_path / "r", "--spp", SPP, "--seed", 9, *set_args(sets))
    cli("reconstruct", "--matrix", tmp_path / "m" / "H_stack.npz", "--capture",
        tmp_path / "r" / "capture.exr", "--method", method, "--iters", 12, "--out", tmp_path / "o")
    stack = stscam.matrix_stack(scene, depth_mm=[400, 480], spp=SPP)
    g = stscam.read_exr(tmp_path / "r" / "capture.exr")["Y"]
    res = stscam.reconstruct_stack(stack, g, method=method, iters=12)
    report = json.load(open(tmp_path / "o" / "recon.json"))
    assert res["solver"] == report["solver"]
    assert sorted(res["planes"]) == [p["depth_mm"] for p in report["planes"]]
    for d, f in res["planes"].items():
        exr = stscam.read_exr(tmp_path / "o" / f"recon_{d:g}mm.exr")["Y"]
        assert same_bits(f.astype(np.float32), exr), d
    if method == "depth":
        assert res["estimate"]["depth_mm"] == 400.0 and list(res["planes"]) == [400.0]
    else:
        assert res["estimate"] is None and len(res["planes"]) == 2
    with pytest.raises(ValueError):
        stscam.reconstruct_stack(stack, g[:-1], method=method)


def test_info_and_probe_equal_cli_json(scene):
    assert stscam.info(scene) == json.loads(cli("info", "--json", *set_args(SETS)).stdout)
    p = stscam.probe(scene, pixel=(10, 20))
    assert p == json.loads(cli("probe", "--pixel", "10,20", "--json", *set_args(SETS)).stdout)
    assert p != stscam.probe(scene, pixel=(10, 21))


@pytest.mark.parametrize("method", ["admm-tv", "cg"])
@pytest.mark.parametrize("rule", ["discrepancy", "fixed"])
def test_reconstruct_equals_cli(scene, tmp_path, method, rule):
    # A sensor quieter than the default 8-bit one, so that this small H (4 spp, a crop that
    # sees part of the object) has signal above the noise in its range; H.json carries it to
    # the CLI, `sensor=` to Python.
    quiet = {"noise.full_well_e": 1e6, "noise.bit_depth": 16}
    # CGM's iterations: 12 fixed, or a cap of 100 the discrepancy principle stops it within.
    it = 100 if (rule, method) == ("discrepancy", "cg") else 12
    sets = set_args({**SETS, **quiet})
    cli("matrix", "--out", tmp_path / "m", "--spp", SPP, *sets)
    h = scipy.sparse.load_npz(tmp_path / "m" / "H.npz")
    off = np.load(tmp_path / "m" / "offset.npy")
    # A capture measured by the scene's sensor (the discrepancy principle's model), the
    # exposure of the all-white capture H·1 + offset given.
    peak = float((h @ np.ones(h.shape[1]) + off).max())
    cli("render", "--out", tmp_path / "r", "--spp", SPP, "--seed", 9, *sets,
        *(("--noise", "sensor", "--white-peak", peak) if rule == "discrepancy" else ()))
    cli("reconstruct", "--matrix", tmp_path / "m" / "H.npz", "--capture",
        tmp_path / "r" / "capture.exr", "--method", method, "--iters", it, "--out", tmp_path / "o",
        "--regularisation", rule)
    g = stscam.read_exr(tmp_path / "r" / "capture.exr")["Y"]
    kw = {"white_peak": peak, "sensor": stscam.Scene(overrides=quiet)} if rule == "discrepancy" else {}
    # Any scipy sparse format is accepted.
    f = stscam.reconstruct(h.tocoo(), g, method=method, iters=it, offset=off,
                           regularisation=rule, **kw)
    assert f.shape == (32, 32) and f.dtype == np.float64
    want = stscam.read_exr(tmp_path / "o" / "recon.exr")["Y"]
    assert same_bits(f.astype(np.float32), want)
    assert not same_bits(stscam.reconstruct(h, g, method=method, iters=it, regularisation=rule,
                                            **kw).astype(np.float32), want)
    if rule == "discrepancy" and method == "admm-tv":
        # The rule's inputs matter: another exposure is another noise level, another τ. (This
        # 4-spp H's own error keeps CGM from the budget within its cap, whatever the noise.)
        other = stscam.reconstruct(h, g, method=method, iters=it, offset=off, white_peak=peak / 4,
                                   sensor=kw["sensor"])
        assert not same_bits(other.astype(np.float32), want)
        # ... and so is another sensor (the default 8-bit one).
        other = stscam.reconstruct(h, g, method=method, iters=it, offset=off, white_peak=peak)
        assert not same_bits(other.astype(np.float32), want)
        rec = json.loads((tmp_path / "o" / "recon.json").read_text())
        assert rec["regularisation"]["white_peak"] == peak
        assert np.abs(f).max() > 0.1  # a reconstruction, not the zero a budget above |g|² gives
        assert rec["regularisation"]["white_peak_source"].endswith("(noise.white_peak)")


def test_reconstruct_rule_refusals(small_h):
    h, off = small_h
    g = np.zeros(h.shape[0])
    with pytest.raises(ValueError, match="tau: sets tau of regularisation=\"fixed\""):
        stscam.reconstruct(h, g, tau=0.01)
    with pytest.raises(ValueError, match="regularisation 'tikhonov': expected"):
        stscam.reconstruct(h, g, regularisation="tikhonov")
    with pytest.raises(ValueError, match="white_peak: sets the discrepancy"):
        stscam.Operator(h, off, object_shape=(32, 32)).reconstruct(
            g, regularisation="fixed", white_peak=1.0)
    with pytest.raises(ValueError, match="white_peak: white peak"):
        stscam.reconstruct(h, g, white_peak=1e300)


def test_calibrate_equals_cli(scene, tmp_path):
    cli("calibrate", "--out", tmp_path, "--spp", SPP, *set_args(SETS))
    h_est, report = stscam.calibrate(scene, spp=SPP)
    h_cli = scipy.sparse.load_npz(tmp_path / "H_est.npz")
    for name in ("data", "indices", "indptr"):
        assert same_bits(getattr(h_est, name), getattr(h_cli, name)), name
    assert report == json.load(open(tmp_path / "calibration.json"))["report"]


def test_sweep_equals_cli_json(scene, tmp_path):
    vary = ["bottom_hoe.height_mm=10:30:2"]
    rows = stscam.sweep(scene, vary=vary)
    assert len(rows) == 2 and rows[0] != rows[1]
    want = json.loads(cli("sweep", "--vary", vary[0], "--json", "--out", tmp_path,
                          *set_args(SETS)).stdout)
    assert rows == want
    assert stscam.sweep(scene, vary={"bottom_hoe.height_mm": (10, 30, 2)}) == want
    # A scene built from a dict sweeps like the same scene from a file (it was refused).
    from_dict = stscam.Scene.from_dict(scene.to_dict())
    assert stscam.sweep(from_dict, vary=vary) == want
    # A changed dict changes the rows (the dict is what is swept, not the paper scene).
    d = scene.to_dict()
    d["plate"]["thickness_mm"] = 2.5
    assert stscam.sweep(stscam.Scene.from_dict(d), vary=vary) != want


# The 96 x 160 crop sees the middle of the target only: the coverage warning is expected.
@pytest.mark.filterwarnings("ignore:warning. object rows")
def test_evaluate_equals_cli_json(tmp_path):
    # Geometry and reconstruction metrics of the paper design at a small fidelity: the dict is
    # the CLI's JSON object (NaN where the CLI writes null), bit for bit.
    sets = {"sensor.crop_px": [96, 160]}
    args = ["--metrics", "fov_capture_vertical_deg,replicas_5pct,psnr_db", "--targets",
            "letter:A,siemens:12", "--object-px", 16, "--spp", 2, "--replicates", 2]
    want = json.loads(cli("evaluate", *args, "--json", *set_args(sets)).stdout)
    got = stscam.evaluate(stscam.Scene(overrides=sets),
                          metrics=["fov_capture_vertical_deg", "replicas_5pct", "psnr_db"],
                          targets=["letter:A", "siemens:12"], object_px=16, spp=2)
    assert set(got) == set(want) and "psnr_db_error" in got
    assert all(got[k] == want[k] for k in want)
    # Another seed changes the PSNR: the equality above can fail.
    other = stscam.evaluate(stscam.Scene(overrides=sets), metrics="psnr_db",
                            targets=["letter:A", "siemens:12"], object_px=16, spp=2, seed=2)
    assert other["psnr_db"] != got["psnr_db"]
    # A target array equals the same image as an EXR file (linear values).
    img = np.random.default_rng(5).random((16, 16)).astype(np.float32)
    stscam.write_exr(tmp_path / "t.exr", {"Y": img})
    by_file = stscam.evaluate(stscam.Scene(overrides=sets), metrics="psnr_db",
                              targets=[tmp_path / "t.exr"], object_px=16, spp=2)
    by_array = stscam.evaluate(stscam.Scene(overrides=sets), metrics="psnr_db",
                               targets=[img], encoding="linear", object_px=16, spp=2)
    assert by_file == by_array
    with pytest.raises(ValueError, match="--metrics"):
        stscam.evaluate(metrics="no_such_metric")
    with pytest.raises(ValueError, match="encoding"):
        stscam.evaluate(metrics="psnr_db", targets=[img])


STUDY = {
    "set": ["sensor.crop_px=[1280,1024]", "plate.thickness_mm=2"],
    "parameter": [{"key": "top_hoe.height_mm", "min": 4.0, "max": 16.0},
                  {"key": "camera.distance_mm", "min": 20.0, "max": 60.0}],
    "objective": [{"metric": "fov_capture_vertical_deg", "goal": "maximize"}],
    "constraint": [{"key": "top_hoe.height_mm", "max": 10.0}],
    "optimizer": {"initial": 4, "batch": 2},
}


def test_optimize_equals_cli(tmp_path):
    study = tmp_path / "s.toml"
    study.write_text(stscam.to_toml(STUDY))
    cli("optimize", study, "--budget", 6, "--seed", 2, "--out", tmp_path / "cli", "--skip-final")
    seen = []
    r = stscam.optimize(STUDY, budget=6, seed=2, skip_final=True, out=tmp_path / "py",
                        progress=lambda d, t, u: seen.append((d, t, u)))
    strip = lambda p: [",".join(l.split(",")[:-1]) for l in open(p).read().splitlines()]
    assert strip(tmp_path / "py" / "history.csv") == strip(tmp_path / "cli" / "history.csv")
    assert len(r.history) == 6 and r.params().shape == (6, 2)
    assert list(r.history[0]["params"]) == ["top_hoe.height_mm", "camera.distance_mm"]
    assert r.best is not None and r.best_scene is not None
    h = r.history[r.best]
    assert h["feasible"] and h["params"]["top_hoe.height_mm"] <= 10.0
    best = r.metric("fov_capture_vertical_deg")[r.best]
    assert best == max(x["metrics"]["fov_capture_vertical_deg"] for x in r.history if x["feasible"])
    # The best scene evaluates to the recorded metric.
    again = stscam.evaluate(r.best_scene, metrics="fov_capture_vertical_deg")
    assert again["fov_capture_vertical_deg"] == best
    assert seen and seen[-1] == (6, 6, "evaluations")
    # Without out= nothing is kept; a bad study raises ValueError naming the key.
    assert stscam.optimize(STUDY, budget=2, skip_final=True).out is None
    bad = dict(STUDY, parameter=[{"key": "top_hoe.height_mm", "min": 16.0, "max": 4.0}])
    with pytest.raises(ValueError, match="parameter"):
        stscam.optimize(bad, budget=2)


def test_oversized_batches_are_refused_before_conversion():
    # 3e6 object views (no memory of their own) and 1e5 targets whose captures would need
    # hundreds of GB: ValueError within a second, before any array is converted (they took
    # 3.5 GB, and past 5 GB with a SIGABRT, before the refusal).
    views = np.broadcast_to(np.zeros((1, 32, 32), np.float32), (3_000_000, 32, 32))
    t0 = time.monotonic()
    with pytest.raises(ValueError, match="objects: 3000000 arrays, at most"):
        stscam.build_dataset(ROOT / "validation" / "python" / "noiseless.toml", "/nonexistent",
                             objects=views, encoding="linear")
    many = np.broadcast_to(np.zeros((1, 64, 64), np.float32), (100_000, 64, 64))
    with pytest.raises(ValueError, match="targets: 100000 arrays need more than"):
        stscam.render_batch(stscam.Scene(), many, encoding="linear")
    # A sequence of arrays is counted item by item the same way.
    with pytest.raises(ValueError, match="targets: 100000 arrays"):
        stscam.render_batch(stscam.Scene(), [many[0]] * 100_000, encoding="linear")
    assert time.monotonic() - t0 < 5.0


def test_build_dataset_from_arrays(tmp_path):
    # Objects given as arrays replace the recipe's sources: sample i's object is objects[i],
    # and (noiseless recipe) its capture is H f + offset of its scene.
    recipe = ROOT / "validation" / "python" / "noiseless.toml"
    objs = np.random.default_rng(3).random((12, 32, 32))
    summary = stscam.build_dataset(recipe, tmp_path / "a", objects=objs, encoding="linear")
    assert summary["samples"] == 12
    seen = []
    for split in ("train", "validation", "test"):
        ds = stscam.load_dataset(tmp_path / "a", split)
        for i in range(len(ds)):
            k = int(ds.metadata[i]["object_draw"].split("index=")[1])
            seen.append(k)
            item = ds[i]
            assert same_bits(item["object"], objs[k].astype(np.float32)), k
            h, off = ds.matrix(i)
            want = h.astype(np.float64) @ objs[k].astype(np.float32).ravel().astype(np.float64) + off
            np.testing.assert_allclose(item["capture"].ravel(), want, rtol=1e-5, atol=1e-9)
    assert sorted(seen) == list(range(12))
    # Display code values: the display gamma is applied, as for generated objects.
    codes = (objs[:3] * 255).astype(np.uint8)
    stscam.build_dataset(recipe, tmp_path / "b", objects=codes, encoding="display")
    gamma = stscam.Scene().to_dict()["display"]["gamma"]
    ds = stscam.load_dataset(tmp_path / "b", "train")
    k = int(ds.metadata[0]["object_draw"].split("index=")[1])
    np.testing.assert_allclose(ds[0]["object"], (codes[k] / 255.0) ** gamma, rtol=1e-5, atol=1e-7)
    # Other arrays are another dataset: resuming into the first one is refused.
    with pytest.raises(ValueError):
        stscam.build_dataset(recipe, tmp_path / "a", objects=objs[::-1], encoding="linear", resume=True)
    with pytest.raises(ValueError, match="size_px"):
        stscam.build_dataset(recipe, tmp_path / "c", objects=np.zeros((2, 16, 16)), encoding="linear")
    with pytest.raises(ValueError, match="encoding"):
        stscam.build_dataset(recipe, tmp_path / "c", objects=objs)


def test_build_dataset_equals_cli_and_loads(tmp_path):
    recipe = ROOT / "validation" / "python" / "noiseless.toml"
    cli("dataset", recipe, "--out", tmp_path / "cli")
    summary = stscam.build_dataset(recipe, tmp_path / "py")
    assert summary["samples"] == 30
    cmp = filecmp.dircmp(tmp_path / "cli", tmp_path / "py")
    def same_tree(c):
        assert not c.left_only and not c.right_only and not c.diff_files, (c.left, c.diff_files)
        for f in c.common_files:
            assert filecmp.cmp(os.path.join(c.left, f), os.path.join(c.right, f), shallow=False), f
        for sub in c.subdirs.values():
            same_tree(sub)
    same_tree(cmp)
    # The loader against the files.
    total = 0
    for split in ("train", "val", "test"):
        ds = stscam.load_dataset(tmp_path / "cli", split)
        lines = (tmp_path / "cli" / split / "metadata.jsonl").read_text().splitlines()
        assert len(ds) == len(lines)
        total += len(ds)
        for i in (0, len(ds) - 1):
            m = json.loads(lines[i])
            item = ds[i]
            assert same_bits(item["object"], np.load(tmp_path / "cli" / split / m["object_npy"]))
            assert same_bits(item["capture"], np.load(tmp_path / "cli" / split / m["capture_npy"]))
            assert item["object"].shape == (32, 32) and item["capture"].shape == (96, 96)
        h, off = ds.matrix(0)
        obj, cap = ds[0]["object"], ds[0]["capture"]
        # Noiseless matrix mode: capture = H f + offset (float32 rounding).
        pred = h @ obj.reshape(-1).astype(np.float64) + off
        assert np.max(np.abs(pred - cap.reshape(-1))) <= 1e-5 * np.max(np.abs(cap))
    assert total == 30
    with pytest.raises(IndexError):
        stscam.load_dataset(tmp_path / "cli", "train")[10_000]
    with pytest.raises(ValueError, match="split"):
        stscam.load_dataset(tmp_path / "cli", "dev")


def cli_error(*args):
    r = cli(*args, check=False)
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("error: ")
    return line[len("error: "):]


def test_bad_input_raises_value_error_with_the_cli_message(tmp_path):
    with pytest.raises(ValueError) as e:
        stscam.Scene(overrides={"plate.thickness_mmm": 3})
    assert str(e.value) == cli_error("info", "--set", "plate.thickness_mmm=3")
    with pytest.raises(ValueError) as e:
        stscam.Scene(overrides={"plate.thickness_mm": -1})
    assert str(e.value) == cli_error("info", "--set", "plate.thickness_mm=-1")
    with pytest.raises(ValueError) as e:
        stscam.Scene(tmp_path / "missing.toml")
    assert str(e.value) == cli_error("info", tmp_path / "missing.toml")
    with pytest.raises(ValueError) as e:
        stscam.render(spp=0)
    assert str(e.value) == cli_error("render", "--spp", "0", "--out", tmp_path / "r")
    with pytest.raises(ValueError) as e:
        stscam.matrix(depth_mm=-5)
    assert str(e.value) == cli_error("matrix", "--depth-mm=-5", "--out", tmp_path / "m")
    with pytest.raises(ValueError) as e:
        stscam.probe(pixel=(100000, 3))
    assert str(e.value) == cli_error("probe", "--pixel", "100000,3")
    with pytest.raises(ValueError) as e:
        stscam.build_dataset(tmp_path / "nope.toml", tmp_path / "d")
    assert str(e.value) == cli_error("dataset", tmp_path / "nope.toml", "--out", tmp_path / "d")
    with pytest.raises(ValueError, match="rows"):
        stscam.reconstruct(scipy.sparse.eye(16, format="csr"), np.zeros(15))
    with pytest.raises(ValueError):
        stscam.render(threads=0)


def test_ctrl_c_stops_a_long_render():
    # Python's own Ctrl-C handler, as in an interactive session: a process started in the
    # background by a non-interactive shell inherits SIGINT ignored, and then
    # _thread.interrupt_main() does nothing.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        check_ctrl_c_stops_a_long_render()
    finally:
        signal.signal(signal.SIGINT, previous)


def test_ctrl_c_stops_a_long_reconstruction(small_h):
    # The CG and ADMM-TV iterations check the cancellation token (before: only renders did).
    h, off = small_h
    op = stscam.Operator(h, off, object_shape=(32, 32))
    g = op.capture(np.full((32, 32), 0.5))
    op.reconstruct(g, method="admm-tv", iters=1, regularisation="fixed")  # the set-up, once
    t0 = time.monotonic()
    op.reconstruct(g, method="admm-tv", iters=200, regularisation="fixed")
    per_iter = (time.monotonic() - t0) / 200
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.5, _thread.interrupt_main)
    try:
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            op.reconstruct(g, method="admm-tv", iters=10**9, regularisation="fixed")
        elapsed = time.monotonic() - t0
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    # 10**9 iterations would take days; the interrupt lands within ~0.1 s plus one iteration.
    assert elapsed < 0.5 + 0.5 + 2 * per_iter, (elapsed, per_iter)


def test_ctrl_c_stops_a_long_set_up():
    # The set-up of a reconstruction (Hᵀ and the Gram matrix HᵀH) checks the cancellation
    # token per row of HᵀH (before: it ran to the end, up to ~40 s on large H). A random H whose
    # Gram costs Σ_m nnz_m² ≈ 7e8 multiply-adds; its time is estimated from an eighth of its rows.
    rng = np.random.default_rng(7)
    rows, cols, per_row = 8192, 2048, 300
    starts = rng.integers(0, cols, rows)
    indices = np.sort((starts[:, None] + np.arange(per_row)) % cols, axis=1)
    indptr = np.arange(rows + 1) * per_row
    data = rng.random(rows * per_row).astype(np.float32)
    h = scipy.sparse.csr_matrix((data, indices.ravel(), indptr), shape=(rows, cols))
    t0 = time.monotonic()
    stscam.Operator(h[: rows // 8], None, object_shape=(32, 64)).reconstruct(
        np.zeros(rows // 8), method="cg", iters=1, regularisation="fixed"
    )
    full = 8 * (time.monotonic() - t0)
    if full < 1.5:
        # A faster machine: stack copies of H's rows (the set-up's cost grows with the rows).
        k = int(np.ceil(1.5 / max(full, 1e-3)))
        h = scipy.sparse.vstack([h] * k, format="csr")
        rows, full = rows * k, full * k
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(0.3, _thread.interrupt_main)
    try:
        timer.start()
        t0 = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            stscam.Operator(h, None, object_shape=(32, 64)).reconstruct(
                np.zeros(rows), method="cg", iters=10**9, regularisation="fixed"
            )
        elapsed = time.monotonic() - t0
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, previous)
    assert full > 1.0, f"the set-up is too quick ({full:.2f} s) to show the interrupt"
    assert elapsed < 0.3 + 0.5, (elapsed, full)


def check_ctrl_c_stops_a_long_render():
    big = stscam.Scene(overrides={"sensor.crop_px": [440, 440]})
    t0 = time.monotonic()
    stscam.render(big, spp=1)
    one = time.monotonic() - t0  # one sample per pixel; 400 would take ~400x as long
    timer = threading.Timer(0.5, _thread.interrupt_main)
    timer.start()
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        stscam.render(big, spp=400)
    elapsed = time.monotonic() - t0
    timer.cancel()
    assert elapsed < 0.5 + max(2.0, 5 * one), (elapsed, one)


# --- Datasets of every kind (2-D above; depth and 3-D here), staying inside their folder ---

def test_load_depth_dataset_and_sensor_noise_equals_its_captures(tmp_path):
    recipe = ROOT / "validation" / "python" / "depth-tiny.toml"
    cli("dataset", recipe, "--out", tmp_path / "d")
    card = json.load(open(tmp_path / "d" / "dataset.json"))
    scene = stscam.Scene(overrides={"sensor.crop_px": [48, 48], "sensor.pitch_um": 44.0})
    n = 0
    for split in ("train", "validation", "test"):
        ds = stscam.load_dataset(tmp_path / "d", split)
        assert ds.kind == "depth"
        folder = "val" if split == "validation" else split
        lines = [json.loads(x) for x in (tmp_path / "d" / folder / "metadata.jsonl").read_text().splitlines()]
        assert len(ds) == len(lines)
        for i, m in enumerate(lines):
            item = ds[i]
            assert same_bits(item["object"], np.load(tmp_path / "d" / folder / m["object_npy"]))
            assert same_bits(item["capture"], np.load(tmp_path / "d" / folder / m["capture_npy"]))
            assert item["depth_mm"] == m["depth_mm"]
            assert item["capture_full_scale"] == card["exposure"]["capture_full_scale"]
            # The noise as a function: the clean capture H f + offset through sensor_noise with
            # the sample's seed is the stored noisy capture, bit for bit.
            h, off = ds.matrix(i)
            clean = h @ item["object"].astype(np.float64).ravel() + off.astype(np.float64)
            wp = card["exposure"]["white_peak"]
            g = stscam.sensor_noise(scene, clean, seed=m["seed"], white_peak=wp)
            assert same_bits(g, item["capture"].ravel())
            # Another seed is other noise: the equality can fail.
            assert not same_bits(stscam.sensor_noise(scene, clean, seed=m["seed"] + 1, white_peak=wp), g)
            n += 1
    assert n == card["samples"] == 8
    assert set(stscam.load_splits(tmp_path / "d")) == {"train", "validation", "test"}
    # "val", the folder's name, is the same split.
    assert len(stscam.load_dataset(tmp_path / "d", "val")) == card["counts"]["val"]


def test_load_3d_dataset_gives_capture_frontal_depth_and_mask(tmp_path):
    from check_dataset import read_png16  # an independent PNG reader (zlib)
    recipe = ROOT / "validation" / "python" / "meshes-tiny.toml"
    cli("dataset", recipe, "--out", tmp_path / "d")
    card = json.load(open(tmp_path / "d" / "dataset.json"))
    for split, folder in (("train", "train"), ("validation", "val"), ("test", "test")):
        ds = stscam.load_dataset(tmp_path / "d", split)
        assert ds.kind == "3d" and len(ds) == card["counts"][folder]
        for i, m in enumerate(ds.metadata):
            item = ds[i]
            d = tmp_path / "d" / folder
            assert "object" not in item
            assert same_bits(item["capture"], np.load(d / m["capture_npy"]))
            assert same_bits(item["frontal"], np.load(d / m["frontal_npy"]))
            assert same_bits(item["depth"], np.load(d / m["depth_npy"]))
            assert same_bits(item["mask"], read_png16(d / m["mask_file_name"]))
            assert item["capture_full_scale"] == card["exposure"]["capture_full_scale"]
            assert ((item["mask"] > 0) <= np.isfinite(item["depth"])).all()
    assert (ds[0]["mask"] > 0).any() or any((stscam.load_dataset(tmp_path / "d")[i]["mask"] > 0).any() for i in range(3))


def test_dataset_reader_stays_inside_its_folder(tmp_path):
    recipe = ROOT / "validation" / "python" / "depth-tiny.toml"
    cli("dataset", recipe, "--out", tmp_path / "d")
    secret = tmp_path / "secret.npy"
    np.save(secret, np.zeros((48, 48), np.float32))
    meta = tmp_path / "d" / "train" / "metadata.jsonl"
    lines = [json.loads(x) for x in meta.read_text().splitlines()]
    ok = stscam.load_dataset(tmp_path / "d")[0]  # untouched: loads
    for bad in ("../../secret.npy", str(secret)):
        lines[0]["capture_npy"] = bad
        meta.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
        with pytest.raises(ValueError, match="outside the dataset folder|relative path inside"):
            stscam.load_dataset(tmp_path / "d")[0]
    # A symbolic link inside the folder leading out of it.
    (tmp_path / "d" / "train" / "link.npy").symlink_to(secret)
    lines[0]["capture_npy"] = "link.npy"
    meta.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    with pytest.raises(ValueError, match="outside the dataset folder"):
        stscam.load_dataset(tmp_path / "d")[0]
    lines[0]["matrix"] = "../../../etc/H.npz"
    meta.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    with pytest.raises(ValueError, match="outside the dataset folder"):
        stscam.load_dataset(tmp_path / "d").matrix(0)
    assert ok["capture"].shape == (48, 48)


# --- The CLI's limits in every Python entry point ---

def test_limits_raise_value_error_at_once_with_the_cli_line(tmp_path):
    t0 = time.monotonic()
    with pytest.raises(ValueError) as e:
        stscam.render(spp=2**40)
    assert str(e.value) == cli_error("render", "--spp", 2**40, "--out", tmp_path / "r")
    with pytest.raises(ValueError) as e:
        stscam.render(threads=5000)
    assert str(e.value) == cli_error("render", "--threads", 5000, "--out", tmp_path / "r")
    with pytest.raises(ValueError) as e:
        stscam.render(spp=2**32 - 1)
    assert str(e.value) == cli_error("render", "--spp", 2**32 - 1, "--out", tmp_path / "r")
    for call in (lambda: stscam.matrix(spp=2**40), lambda: stscam.matrix(spp=2**32 - 1),
                 lambda: stscam.calibrate(threads=2**70), lambda: stscam.render(seed=-1),
                 lambda: stscam.render(seed=2**64), lambda: stscam.sweep(psnr_spp=2**33),
                 lambda: stscam.probe(pixel=(2**80, 0)), lambda: stscam.render(frontal_px=0)):
        with pytest.raises(ValueError):  # not OverflowError, not RuntimeError
            call()
    assert time.monotonic() - t0 < 10


def test_nan_stack_offset_is_refused(scene):
    stack = stscam.matrix_stack(scene, depth_mm=[400, 480], spp=1)
    g = np.ones(48 * 64)
    bad = [(d, h, off.copy()) for d, h, off in stack]
    bad[1][2][5] = np.nan
    with pytest.raises(ValueError, match="offset value 5 is not a finite number"):
        stscam.reconstruct_stack(bad, g, method="depth", iters=2)
    with pytest.raises(ValueError, match="offset: value 7 is not a finite number"):
        o = np.zeros(48 * 64, np.float32)
        o[7] = np.inf
        stscam.reconstruct_stack(stack, g, offset=o, iters=2)
    with pytest.raises(ValueError, match="offset: value 3 is not a finite number"):
        o = np.zeros(48 * 64, np.float32)
        o[3] = np.nan
        stscam.reconstruct(stack[0][1], g, offset=o, iters=2)


# --- Arrays in ---

def test_array_target_equals_cli_render_of_the_same_exr(tmp_path):
    rng = np.random.default_rng(4)
    f = rng.random((20, 28)).astype(np.float32)
    stscam.write_exr(tmp_path / "obj.exr", {"Y": f})
    sets = {"sensor.crop_px": [64, 48], "display.image": str(tmp_path / "obj.exr")}
    cli("render", "--out", tmp_path / "r", "--spp", SPP, *set_args(sets))
    want = stscam.read_exr(tmp_path / "r" / "capture.exr")["Y"]
    small = stscam.Scene(overrides={"sensor.crop_px": [64, 48]})
    got = stscam.render(small, spp=SPP, target=f, encoding="linear").image
    assert same_bits(got, want)
    # The scene keeps the array in memory; the file's scene agrees with it.
    kept = small.with_image(f, "linear")
    assert same_bits(stscam.render(kept, spp=SPP).image, want)
    assert same_bits(stscam.render(stscam.Scene(overrides=sets), spp=SPP).image, want)
    # A different array gives other numbers (the check can fail); "display" applies the gamma.
    assert not same_bits(stscam.render(small, spp=SPP, target=f[::-1], encoding="linear").image, want)
    assert not same_bits(stscam.render(small, spp=SPP, target=f, encoding="display").image, want)
    # Linear RGB: reduced to luminance as the EXR reader does.
    rgb = rng.random((20, 28, 3)).astype(np.float32)
    stscam.write_exr(tmp_path / "rgb.exr", {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]})
    cli("render", "--out", tmp_path / "c", "--spp", SPP, *set_args(dict(sets, **{"display.image": str(tmp_path / "rgb.exr")})))
    assert same_bits(stscam.render(small, spp=SPP, target=rgb, encoding="linear").image,
                     stscam.read_exr(tmp_path / "c" / "capture.exr")["Y"])
    with pytest.raises(ValueError, match="encoding"):
        stscam.render(small, target=f)
    with pytest.raises(ValueError, match="not a finite number"):
        stscam.render(small, target=np.full((4, 4), np.nan), encoding="linear")


def test_builtin_target_as_array_dtypes_and_batch(scene):
    F = stscam.target("letter:F@32")
    assert F.shape == (32, 32) and F.dtype == np.float32 and set(np.unique(F)) <= {0.0, 1.0}
    ref = stscam.render(scene, spp=SPP).image  # display.image = letter:F@32
    assert same_bits(stscam.render(scene, spp=SPP, target=F, encoding="display").image, ref)
    assert same_bits(stscam.render(scene, spp=SPP, target=(F * 255).astype(np.uint8), encoding="display").image, ref)
    assert same_bits(stscam.render(scene, spp=SPP, target=(F * 65535).astype(np.uint16), encoding="display").image, ref)
    batch = [F, F[::-1], stscam.target("siemens:8@32")]
    out = stscam.render_batch(scene, batch, encoding="display", spp=SPP)
    assert out.shape == (3, 48, 64)
    for i, t in enumerate(batch):
        assert same_bits(out[i], stscam.render(scene, spp=SPP, target=t, encoding="display").image), i
    assert not same_bits(out[0], out[1])
    with pytest.raises(ValueError, match="invalid target"):
        stscam.target("letter:")


def test_camera_table_equals_the_cli_and_serves_a_batch(scene, tmp_path):
    # A display scene: the CLI's table render and Python's agree bit for bit, and a batch of
    # targets is summed over the same table (read once).
    cache = tmp_path / "cache"
    cli("render", "--out", tmp_path / "t", "--spp", SPP, "--camera-table", cache, "--table-spp", 16,
        "--table-reps", 8, *set_args(SETS))
    want = stscam.read_exr(tmp_path / "t" / "capture.exr")["Y"]
    got = stscam.render(scene, spp=SPP, camera_table=cache, table_spp=16, table_reps=8).image
    assert same_bits(got, want)
    assert len(list(cache.iterdir())) == 1
    F = stscam.target("letter:F@32")
    out = stscam.render_batch(scene, [F, F[::-1]], encoding="display", spp=SPP, camera_table=cache,
                              table_spp=16, table_reps=8)
    assert same_bits(out[0], want)
    assert not same_bits(out[1], want)
    # Other table settings are another file; bad ones raise ValueError.
    stscam.render(scene, spp=SPP, camera_table=cache, table_spp=8, table_reps=8)
    assert len(list(cache.iterdir())) == 2
    with pytest.raises(ValueError, match="table_reps"):
        stscam.render(scene, camera_table=cache, table_reps=0)
    with pytest.raises(ValueError, match="--spectral"):
        stscam.render(scene, camera_table=cache, spectral=True)


def test_adaptive_render_equals_cli_and_records_its_counts(scene, tmp_path):
    # render(adaptive=True) is `render --adaptive` bit for bit, with the counts in its stats;
    # too few samples raise ValueError with the CLI's line.
    cli("render", "--out", tmp_path / "a", "--spp", 16, "--adaptive", *set_args(SETS))
    want = stscam.read_exr(tmp_path / "a" / "capture.exr")["Y"]
    r = stscam.render(scene, spp=16, adaptive=True)
    assert same_bits(r.image, want)
    counts = r.stats["sample_counts"]
    side = json.loads((tmp_path / "a" / "capture.json").read_text())["stats"]["sample_counts"]
    assert counts == side and counts["pilot_spp"] == 1 and counts["max_spp"] > 16
    assert not same_bits(r.image, stscam.render(scene, spp=16).image)
    with pytest.raises(ValueError, match="--adaptive needs --spp of at least 16"):
        stscam.render(scene, spp=8, adaptive=True)
    # A batch gives each target its own pilot: the first is the single render's image.
    F = stscam.target("letter:F@32")
    out = stscam.render_batch(scene, [F, F[::-1]], encoding="display", spp=16, adaptive=True)
    assert same_bits(out[0], want) and not same_bits(out[1], want)


def test_render_with_sensor_noise_is_sensor_noise_of_the_clean_render(scene):
    clean = stscam.render(scene, spp=SPP, seed=3).image
    noisy = stscam.render(scene, spp=SPP, seed=3, noise="sensor", white_peak=0.05).image
    assert same_bits(noisy, stscam.sensor_noise(scene, clean, seed=3, white_peak=0.05))
    assert not same_bits(noisy, clean)
    # A white peak whose full scale does not fit float32 is refused, not stored as infinity.
    for bad in (1e300, 1e-300, 0.0, float("nan")):
        with pytest.raises(ValueError, match="white peak|white_peak"):
            stscam.sensor_noise(scene, clean, seed=3, white_peak=bad)
    assert np.isfinite(stscam.sensor_noise(scene, clean * 1e30, seed=3, white_peak=1e36)).all()


# --- Framing warnings and conventions ---

def test_python_warns_as_the_cli_when_part_of_the_object_is_unseen(tmp_path):
    sets = {"sensor.crop_px": [96, 96], "display.image": "letter:F@32"}
    r = cli("matrix", "--out", tmp_path, "--spp", 1, *set_args(sets))
    line = [x for x in r.stderr.splitlines() if x.startswith("warning: ")]
    assert line and "object rows" in line[0]
    with pytest.warns(UserWarning) as w:
        stscam.matrix(stscam.Scene(overrides=sets), spp=1)
    assert [str(x.message) for x in w] == [line[0][len("warning: "):]]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a framed object gives no warning
        stscam.matrix(stscam.Scene(overrides={"sensor.crop_px": [96, 160], "display.image": "letter:F@16"}), spp=1)


def test_frontal_spp_equals_cli_and_leaves_the_capture(tmp_path):
    path = ROOT / "scenes" / "gesture.toml"
    sets = {"sensor.crop_px": [16, 16], "sensor.pitch_um": 60.0}
    cli("render", path, "--out", tmp_path, "--spp", 1, "--frontal-spp", 4, *set_args(sets))
    s = stscam.Scene(path, sets)
    r = stscam.render(s, spp=1, frontal_spp=4)
    assert same_bits(r.frontal, stscam.read_exr(tmp_path / "frontal.exr")["Y"])
    plain = stscam.render(s, spp=1)
    assert same_bits(r.image, plain.image) and not same_bits(r.frontal, plain.frontal)
    with pytest.raises(ValueError, match="frontal-spp"):
        stscam.render(s, spp=1, frontal_spp=0)


def test_frontal_px_takes_one_number_like_the_cli(tmp_path):
    path = ROOT / "scenes" / "gesture.toml"
    s = stscam.Scene(path, {"sensor.crop_px": [16, 16], "sensor.pitch_um": 60.0})
    a = stscam.render(s, spp=1, frontal_px=12)
    assert a.frontal.shape == (12, 12)
    assert same_bits(stscam.render(s, spp=1, frontal_px="12").frontal, a.frontal)
    assert stscam.render(s, spp=1, frontal_px="16x12").frontal.shape == (12, 16)


# --- The operator ---

@pytest.fixture(scope="module")
def small_h(scene):
    return stscam.matrix(scene, spp=SPP)


def test_operator_adjoint_batches_and_scipy(small_h):
    h, off = small_h
    op = stscam.Operator(h, off, object_shape=(32, 32), capture_shape=(48, 64))
    rng = np.random.default_rng(1)
    x = rng.random((3, 32, 32))
    y = rng.standard_normal((3, 48, 64))
    hx, hty = op.forward(x), op.adjoint(y)
    assert hx.shape == (3, 48, 64) and hty.shape == (3, 32, 32)
    for i in range(3):
        lhs, rhs = np.vdot(hx[i], y[i]), np.vdot(x[i], hty[i])
        assert abs(lhs - rhs) <= 1e-6 * np.linalg.norm(hx[i]) * np.linalg.norm(y[i])
        # Batch equals a loop, and both equal scipy's product with H.
        assert same_bits(op.forward(x[i]), hx[i])
        assert np.array_equal(hx[i].ravel(), h.astype(np.float64) @ x[i].ravel())
    # A wrong adjoint (H's transpose with one entry changed) fails the same test.
    bad = h.astype(np.float64).T.tocsr()
    bad.data[np.argmax(bad.data)] *= 2
    lhs, rhs = np.vdot(hx[0], y[0]), np.vdot(x[0], (bad @ y[0].ravel()).reshape(32, 32))
    assert abs(lhs - rhs) > 1e-6 * np.linalg.norm(hx[0]) * np.linalg.norm(y[0])
    L = op.scipy()
    assert np.array_equal(L.matvec(x[0].ravel()), hx[0].ravel())
    assert np.array_equal(L.rmatvec(y[0].ravel()), hty[0].ravel())
    assert np.allclose(op.capture(x[0]).ravel(), hx[0].ravel() + off)


@pytest.mark.parametrize("method", ["cg", "admm-tv"])
def test_operator_reconstruct_equals_reconstruct_and_batches(small_h, scene, method):
    h, off = small_h
    op = stscam.Operator(h, off, object_shape=(32, 32), capture_shape=(48, 64))
    g = np.stack([stscam.render(scene, spp=SPP, seed=s).image for s in (7, 8)])
    batch, infos = op.reconstruct(g, method=method, iters=8, return_info=True)
    assert batch.shape == (2, 32, 32) and len(infos) == 2
    for i in range(2):
        one = stscam.reconstruct(h, g[i], method=method, iters=8, offset=off)
        assert same_bits(batch[i], one), i
    assert not same_bits(batch[0], batch[1])


def test_operator_torch_gradient_and_batch(small_h):
    # Runs wherever torch is installed (.ci/run installs it); skipped only without torch.
    torch = pytest.importorskip("torch")
    h, off = small_h
    op = stscam.Operator(h, off, object_shape=(32, 32))
    A = op.torch()
    x = torch.rand(3, 32, 32, dtype=torch.float64, requires_grad=True)
    y = A(x)
    assert y.shape == (3, 48 * 64)
    # A batch equals a loop over its frames, bit for bit, forward and adjoint, in float64 and
    # float32, and equals the numpy operator.
    for i in range(3):
        assert torch.equal(y[i], A(x[i]))
    assert np.array_equal(y.detach().numpy(), op.forward(x.detach().numpy()))
    w = torch.rand(3, 48 * 64, dtype=torch.float64)
    hw = A.adjoint(w)
    assert hw.shape == (3, 32, 32)
    for i in range(3):
        assert torch.equal(hw[i], A.adjoint(w[i]))
    assert np.array_equal(hw.numpy(), op.adjoint(w.numpy()))
    x32 = x.detach().float()
    assert y.dtype == torch.float64 and A(x32).dtype == torch.float32
    assert torch.equal(A(x32)[2], A(x32[2]))
    # Autograd: the backward of A is the adjoint, and of A.adjoint the forward.
    (y * w).sum().backward()
    assert np.allclose(x.grad.numpy(), op.adjoint(w.numpy()), rtol=1e-12, atol=0)
    w.requires_grad_(True)
    v = torch.rand(3, 32, 32, dtype=torch.float64)
    (A.adjoint(w) * v).sum().backward()
    assert np.allclose(w.grad.numpy(), op.forward(v.numpy()), rtol=1e-12, atol=0)
    # torch's numerical gradient check on a small block of H (its 16 strongest columns and the
    # 40 strongest rows of those: a block of zeros would pass any check), both directions.
    cols = np.argsort(-np.asarray(abs(h).sum(axis=0)).ravel(), kind="stable")[:16]
    sub = h.tocsc()[:, cols].tocsr()
    rows = np.argsort(-np.asarray(abs(sub).sum(axis=1)).ravel(), kind="stable")[:40]
    block = sub[rows]
    assert block.nnz > 40
    small = stscam.Operator(block, None, object_shape=(4, 4))
    B = small.torch()
    assert torch.autograd.gradcheck(B, (torch.rand(2, 4, 4, dtype=torch.float64, requires_grad=True),))
    assert torch.autograd.gradcheck(B.adjoint, (torch.rand(2, 40, dtype=torch.float64, requires_grad=True),))
    # A wrong backward fails the same check: the adjoint scaled by 2.
    class Wrong(torch.autograd.Function):
        @staticmethod
        def forward(ctx, t):
            return B(t)

        @staticmethod
        def backward(ctx, g):
            return 2 * B.adjoint(g)

    with pytest.raises(RuntimeError):  # torch's GradcheckError
        torch.autograd.gradcheck(Wrong.apply, (torch.rand(1, 4, 4, dtype=torch.float64, requires_grad=True),))


def test_operator_deepinv_physics_with_the_sensor_noise(scene, small_h):
    torch = pytest.importorskip("torch")
    pytest.importorskip("deepinv")
    h, off = small_h
    op = stscam.Operator(h, off, object_shape=(32, 32))
    x = torch.rand(3, 1, 32, 32, dtype=torch.float64)
    clean = op.deepinv()
    y = clean.A(x)
    assert y.shape == (3, 1, 48 * 64)
    assert np.array_equal(y.numpy().reshape(3, -1), op.forward(x.numpy().reshape(3, 32, 32)))
    # Adjoint: <A x, w> = <x, Aᵀ w> to rounding.
    w = torch.rand_like(y)
    lhs, rhs = float((y * w).sum()), float((x * clean.A_adjoint(w)).sum())
    assert abs(lhs - rhs) <= 1e-9 * abs(lhs)
    # The sensor noise: measurement b of the first noisy call is the dataset's noise with
    # seed 7 + b, offset added before and removed after.
    noisy = op.deepinv(sensor=scene, seed=7, white_peak=0.05)
    yn = noisy(x)
    for b in range(3):
        g = op.capture(x[b, 0].numpy())
        want = stscam.sensor_noise(scene, g, seed=7 + b, white_peak=0.05).astype(np.float64) - off
        assert np.allclose(yn[b, 0].numpy(), want, rtol=0, atol=1e-12), b
    assert not torch.equal(noisy(x), yn)  # the next call draws new noise
    with pytest.raises(ValueError):
        op.deepinv(noise_model=object(), sensor=scene)


# --- Scenes in Python ---

def test_scene_from_dict_round_trips_with_objects_and_lights(tmp_path):
    s = stscam.Scene("gesture", {"sensor.crop_px": [16, 16], "sensor.pitch_um": 60.0})
    d = s.to_dict()
    assert d["object"][0]["mesh"] == "hand" and len(d["light"]) == 3
    back = stscam.Scene.from_dict(d)
    assert back.to_dict() == d
    assert same_bits(stscam.render(back, spp=1).image, stscam.render(s, spp=1).image)
    # The shipped scene by name is the repository's file.
    f = stscam.Scene(ROOT / "scenes" / "gesture.toml", {"sensor.crop_px": [16, 16], "sensor.pitch_um": 60.0})
    assert f.to_dict() == d
    assert set(stscam.scenes()) >= {"paper-2022", "eye-contact", "gesture"}
    # Objects and lights added from Python: a second object and no environment light.
    d2 = json.loads(json.dumps(d))
    d2["object"].append(dict(d2["object"][0], mesh="head", position_mm=[0.0, 0.0, -400.0]))
    d2["light"] = d2["light"][:2]
    s2 = stscam.Scene.from_dict(d2)
    assert [o["mesh"] for o in s2.to_dict()["object"]] == ["hand", "head"]
    assert len(s2.to_dict()["light"]) == 2
    assert not same_bits(stscam.render(s2, spp=1).image, stscam.render(s, spp=1).image)
    # A bad key raises the loader's one line.
    with pytest.raises(ValueError, match="thickness_mmm"):
        stscam.Scene.from_dict({"plate": {"thickness_mmm": 3.0}})
    with pytest.raises(ValueError, match="not a shipped scene"):
        stscam.Scene.named("nope")


def test_stscam_command_is_the_cli(tmp_path):
    import sys
    cmd = Path(sys.executable).parent / "stscam"
    runs = [[str(cmd)]] if cmd.exists() else []
    runs.append([sys.executable, "-m", "stscam"])
    want = cli("info", "--json", *set_args(SETS)).stdout
    for run in runs:
        r = subprocess.run([*run, "info", "--json", *set_args(SETS)], capture_output=True, text=True)
        assert r.returncode == 0 and json.loads(r.stdout) == json.loads(want), r.stderr
        bad = subprocess.run([*run, "render", "--spp", "0", "--out", str(tmp_path)], capture_output=True, text=True)
        assert bad.returncode == 2 and bad.stderr.strip() == "error: --spp: must be at least 1"


# --- Progress callbacks (issue 25, item 5) ---

def test_progress_callback_follows_a_dataset_and_a_render(tmp_path):
    calls = []
    recipe = ROOT / "validation" / "python" / "depth-tiny.toml"
    stscam.build_dataset(recipe, tmp_path / "d", progress=lambda *a: calls.append(a))
    n_samples = sum(len((tmp_path / "d" / f / "metadata.jsonl").read_text().splitlines())
                    for f in ("train", "val", "test") if (tmp_path / "d" / f / "metadata.jsonl").exists())
    assert calls, "the callback was never called"
    # Phases in order (the depth dataset's matrix stack, then its samples); within each phase
    # the count never goes back and the total stays; every phase ends complete.
    phases = []
    for done, total, unit in calls:
        if not phases or phases[-1][0] != (unit, total):
            phases.append(((unit, total), []))
        phases[-1][1].append(done)
    for (unit, total), dones in phases:
        assert dones == sorted(dones) and dones[-1] == total > 0, (unit, total, dones)
    assert phases[-1][0] == ("samples", n_samples), phases
    # A render reports its own units, complete at the end.
    calls.clear()
    scene = stscam.Scene(overrides={"sensor.crop_px": [48, 40]})
    stscam.render(scene, spp=2, progress=lambda *a: calls.append(a))
    assert calls and calls[-1][0] == calls[-1][1] > 0, calls


def test_an_exception_in_the_progress_callback_stops_the_job(tmp_path):
    class Stop(Exception):
        pass

    def stop(done, total, unit):
        raise Stop()

    big = stscam.Scene(overrides={"sensor.crop_px": [440, 440]})
    t0 = time.monotonic()
    with pytest.raises(Stop):
        stscam.render(big, spp=400, progress=stop)  # ~400x a one-sample render if not stopped
    assert time.monotonic() - t0 < 10.0
    with pytest.raises(ValueError, match="progress"):
        stscam.render(big, spp=1, progress="yes")


def test_emva1288_photon_transfer_recovers_the_sensor():
    """validation/python/emva1288.py: the EMVA 1288 photon-transfer method recovers the
    sensor's K, temporal dark noise, saturation capacity, DSNU, PRNU, dark current and its
    temperature doubling from stscam's simulated frames within the stated tolerances; a sensor
    with twice the PRNU, checked against the datasheet value, fails."""
    import io

    import emva1288
    log = io.StringIO()
    assert emva1288.run(out=log), log.getvalue()
    doubled = {**emva1288.SENSOR, "noise.prnu": 2 * emva1288.SENSOR["noise.prnu"]}
    assert not emva1288.run(doubled, claimed=emva1288.SENSOR, out=log)
    # Every term off is the ideal sensor of earlier versions: the same values bit for bit.
    clean = np.linspace(0.0, 1.3, 4096)
    ideal = stscam.Scene(overrides={"noise.bit_depth": 12})
    off = stscam.Scene(overrides={"noise.bit_depth": 12, "noise.prnu": 0.0, "noise.dsnu_e": 0.0,
                                  "noise.sensor_seed": 9})
    a = stscam.sensor_noise(ideal, clean, seed=3, white_peak=1.0)
    b = stscam.sensor_noise(off, clean, seed=3, white_peak=1.0)
    assert np.array_equal(a, b)


# --- Colour H in Python (issue 43, item 2) ---

# A small RGB-multiplex camera whose 8 x 8 colour object fills a 40 x 64 Bayer crop.
RGB = {"sensor.crop_px": [40, 64], "sensor.pitch_um": 30, "sensor.crop_offset_px": [0, -10],
       "sensor.response": "rgb-bayer", "display.primaries": "lcd",
       "display.image": "rgb:letter:F@8+black@8+black@8",
       "display.lcd_pixels_per_image_pixel": 40}


def test_colour_operator_and_reconstruct_equal_the_cli(tmp_path):
    scene = ROOT / "scenes" / "rgb-multiplex.toml"
    cli("matrix", scene, "--out", tmp_path / "m", "--spp", SPP, *set_args(RGB))
    cli("render", scene, "--out", tmp_path / "r", "--spp", SPP, "--seed", 1, *set_args(RGB))
    h = scipy.sparse.load_npz(tmp_path / "m" / "H.npz")
    off = np.load(tmp_path / "m" / "offset.npy")
    op = stscam.Operator(h, off, object_shape=(8, 8))
    assert (op.planes, op.object_dims) == (3, (3, 8, 8))
    # The operator holds the CLI's H bit for bit.
    assert same_bits(op.H.data, h.astype(np.float32).data) and np.array_equal(op.H.indices, h.indices)
    # Adjointness, batched: <H x, y> = <x, Hᵀ y> to 1e-9 (relative).
    rng = np.random.default_rng(3)
    x, y = rng.random((2, 3, 8, 8)), rng.random((2, h.shape[0]))
    hx, hty = op.forward(x), op.adjoint(y)
    assert hx.shape == (2, h.shape[0]) and hty.shape == (2, 3, 8, 8)
    for i in range(2):
        lhs, rhs = np.vdot(hx[i], y[i]), np.vdot(x[i], hty[i])
        assert abs(lhs - rhs) <= 1e-9 * abs(lhs), (lhs, rhs)
    # The red F in the R plane (channel first) gives the render of the same seed (H f + offset
    # equals the tracer to float rounding); the same F swapped into the B plane does not.
    truth = np.zeros((3, 8, 8))
    truth[0] = stscam.target("letter:F@8").astype(np.float64) ** 2.2
    cap = stscam.read_exr(tmp_path / "r" / "capture.exr")
    g = np.concatenate([cap[c].reshape(-1) for c in ("R", "G", "B")]).astype(np.float64)
    peak = np.abs(g).max()
    assert np.abs(op.capture(truth) - g).max() <= 1e-5 * peak
    assert np.abs(op.capture(truth[::-1]) - g).max() > 0.1 * peak
    # Reconstruction: (3, h, w), equal to the CLI's recon.exr bit for bit (both rules).
    for rule in ("fixed", "discrepancy"):
        cli("reconstruct", "--matrix", tmp_path / "m" / "H.npz", "--capture",
            tmp_path / "r" / "capture.exr", "--out", tmp_path / f"o-{rule}",
            "--regularisation", rule, "--iters", 20)
        want = stscam.read_exr(tmp_path / f"o-{rule}" / "recon.exr")
        f = stscam.reconstruct(h, g, offset=off, object_shape=(8, 8), regularisation=rule, iters=20)
        assert f.shape == (3, 8, 8)
        for k, c in enumerate("RGB"):
            assert same_bits(f[k].astype(np.float32), want[c]), (rule, c)
        fo = op.reconstruct(g, regularisation=rule, iters=20)
        assert same_bits(fo, f), rule
    # The red F reconstructs into R.
    share = f.clip(0).sum(axis=(1, 2)) / f.clip(0).sum()
    assert share[0] > 0.8, share
    with pytest.raises(ValueError, match="a colour H has 3·48 = 144"):
        stscam.Operator(h, off, object_shape=(6, 8))


def test_colour_calibrate_equals_the_cli(tmp_path):
    scene = ROOT / "scenes" / "rgb-multiplex.toml"
    cli("calibrate", scene, "--out", tmp_path, "--spp", SPP, "--dark-frame", *set_args(RGB))
    h_est, report = stscam.calibrate(stscam.Scene(scene, RGB), spp=SPP, dark_frame=True)
    want = scipy.sparse.load_npz(tmp_path / "H_est.npz")
    assert h_est.shape == want.shape == (64 * 40 * 3, 3 * 64)
    assert same_bits(h_est.data, want.data) and np.array_equal(h_est.indices, want.indices)
    cal = json.loads((tmp_path / "calibration.json").read_text())
    assert sorted(report) == ["B", "G", "R"] and report == cal["report_per_primary"]

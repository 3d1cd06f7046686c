"""The certified cascade: the band rule against every band enumerated, its guarantees on the calibration
set, applying it, the handler's verification through it, the pipeline stage's metrics and the API
(``run.detect(x, certify=...)``, ``run.resolve(..., certify=...)``) on a small latent space of tubes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from neuralcol.errors import UserInputError
from neuralcol.metrics.cascade import Band, apply_band, band_mask, cascade_scores, choose_band, error_budget

ROOT = Path(__file__).resolve().parents[1]


def _compose(overrides=()):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def _split(logit, y, lo, hi):
    """(exact calls, errors, FN) of the band [lo, hi) on labeled samples."""
    fn = int((y & (logit < lo)).sum())
    return int(((logit >= lo) & (logit < hi)).sum()), fn + int((~y & (logit >= hi)).sum()), fn


def _brute_force(logit, y, target, min_accuracy):
    """The rule by enumeration: every (lo, hi) pair, lo <= hi, over -inf, the logits, the midpoints and +inf; the
    feasible one with the fewest calls, then the fewest errors, then the largest lo."""
    k = np.floor(target * y.sum() + 1e-9)
    budget = error_budget(logit, y, min_accuracy)
    u = np.unique(logit)
    cand = np.concatenate([[-np.inf], u, (u[1:] + u[:-1]) / 2, [np.inf]])
    best = None
    for lo in cand:
        for hi in cand[cand >= lo]:
            calls, errors, fn = _split(logit, y, lo, hi)
            if fn <= k and errors <= budget:
                key = (calls, errors, -lo)
                if best is None or key < best[0]:
                    best = (key, lo, hi)
    return best


@pytest.mark.parametrize("seed", range(6))
def test_choose_band_is_the_enumerated_optimum(seed):
    rng = np.random.default_rng(seed)
    for _ in range(25):
        n = int(rng.integers(1, 30))
        logit = np.round(rng.normal(0, 2, n), 1)  # ties on purpose
        y = rng.random(n) < 1 / (1 + np.exp(-1.5 * logit))
        if not y.any():
            continue
        target = float(rng.choice([0.0, 0.05, 0.1, 0.25, 0.5]))
        floor = rng.choice(["detector", 0.6, 0.9])
        floor = floor if floor == "detector" else float(floor)
        band = choose_band(logit, y, target, floor)
        (calls, errors, _), lo, _ = _brute_force(logit, y, target, floor)
        assert band.lo == lo
        assert _split(logit, y, band.lo, band.hi)[:2] == (calls, errors)
        assert band.calib_exact_share == pytest.approx(calls / n)
        assert band.calib_accuracy == pytest.approx(1 - errors / n)
        assert band.calib_fnr == pytest.approx((y & (logit < band.lo)).sum() / y.sum())


def test_guarantees_on_the_calibration_set():
    """FNR <= target, never less accurate than the detector alone (or the float floor), fewest calls for None."""
    rng = np.random.default_rng(0)
    y = rng.random(2000) < 0.3
    logit = rng.normal(0, 1.5, 2000) + np.where(y, 1.5, -1.5)
    alone = ((logit > 0) == y).mean()
    alone_fnr = (y & (logit <= 0)).sum() / y.sum()
    shares = []
    for target in (0.0, 0.01, 0.02, 0.05, 0.2):
        b = choose_band(logit, y, target)
        assert b.calib_fnr <= target and b.lo <= b.hi
        assert b.calib_accuracy >= alone - 1e-12
        verdict, used = apply_band(logit, b, lambda rows: y[rows])
        assert (verdict[~used] == (logit[~used] >= b.hi)).all()
        assert (~verdict & y).sum() / y.sum() == pytest.approx(b.calib_fnr)
        assert (verdict == y).mean() == pytest.approx(b.calib_accuracy)
        shares.append(b.calib_exact_share)
        f = choose_band(logit, y, target, 0.95)
        assert f.calib_accuracy >= 0.95 and f.calib_fnr <= target
        none = choose_band(logit, y, target, None)
        assert none.lo == none.hi and none.calib_exact_share == 0 and none.calib_fnr <= target
        assert (y & (logit < np.nextafter(none.lo, np.inf))).sum() > np.floor(target * y.sum() + 1e-9) or \
            none.lo == np.inf  # the largest lo: any larger misses one colliding sample too many
    assert shares == sorted(shares, reverse=True) and shares[0] > shares[-1]  # a looser target: fewer calls
    assert alone_fnr > 0.02  # (so the 0.01 / 0.02 targets above needed a band)


def test_pointwise_floor_holds_on_other_samples():
    """min_accuracy="pointwise": on a fresh draw, every verdict is the exact one or the detector alone's, so the
    cascade is never less accurate there; "detector" holds its floor on calibration only (here it drops below)."""
    rng = np.random.default_rng(5)

    def draw(n):
        y = rng.random(n) < 0.3
        return rng.normal(0, 1.5, n) + np.where(y, 1.0, -1.5), y

    (lc, yc), (lt, yt) = draw(1500), draw(20000)
    below = []
    for target in (0.0, 0.01, 0.05, 0.3, 0.9):
        b = choose_band(lc, yc, target, "pointwise")
        assert b.lo <= 0 < b.hi and b.calib_fnr <= target
        verdict, used = apply_band(lt, b, lambda rows: yt[rows])
        assert ((verdict == yt) | (verdict == (lt > 0))).all()
        assert (verdict == yt).mean() >= ((lt > 0) == yt).mean()
        d = choose_band(lc, yc, target)
        assert b.calib_exact_share >= d.calib_exact_share
        below.append(cascade_scores(lt, yt, d)["accuracy"] < ((lt > 0) == yt).mean())
    assert any(below)  # (what "pointwise" is for)
    b = choose_band(np.array([1.0, 2.0, 3.0]), np.array([True, False, True]), 0.0, "pointwise")
    assert (b.lo, b.hi) == (1.0, 1.0)  # every logit > 0: nothing below lo, the detector's verdicts kept


def test_edge_cases():
    # separable: the detector alone is right everywhere, so no band is needed (lo == hi)
    logit = np.array([-3.0, -2.0, -1.0, 1.0, 2.0, 3.0])
    y = logit > 0
    b = choose_band(logit, y, 0.0)
    assert b.lo == b.hi and b.calib_exact_share == 0 and b.calib_fnr == 0 and b.calib_accuracy == 1
    # the detector's own FNR (0) is below the target: the largest lo meeting the target alone (2.0, missing one
    # colliding sample) would exceed the detector's error budget (0) whatever hi; the band stays empty at lo = 1.0
    b = choose_band(logit, y, 0.4)
    assert b.lo == b.hi == 1.0 and b.calib_fnr == 0 and b.calib_accuracy == 1
    # every sample colliding with low logits: the band covers what the target needs
    b = choose_band(np.array([-3.0, -2.0, -1.0]), np.ones(3, bool), 0.0)
    assert b.lo == -3.0 and b.calib_fnr == 0
    with pytest.raises(ValueError, match="none of the 3 calibration samples collides"):
        choose_band(np.zeros(3), np.zeros(3, bool), 0.01)
    for bad in (1.0, -0.1):
        with pytest.raises(ValueError, match="target_fnr"):
            choose_band(logit, y, bad)
    with pytest.raises(ValueError, match="min_accuracy"):
        choose_band(logit, y, 0.1, "best")
    with pytest.raises(ValueError, match="min_accuracy"):
        choose_band(logit, y, 0.1, 1.5)
    with pytest.raises(ValueError, match="non-finite"):
        choose_band(np.array([0.0, np.nan]), np.array([True, False]), 0.1)


def test_apply_band_asks_the_exact_labeler_for_the_band_rows_only():
    logit = np.array([-5.0, -1.0, -0.5, 0.0, 0.5, 1.0, 5.0])
    band = Band(-1.0, 0.5, 0.0, 1.0, 0.0)
    asked = []

    def exact_fn(rows):
        asked.append(rows.copy())
        return np.ones(len(rows), bool)  # "collides", whatever the network says

    verdict, used = apply_band(logit, band, exact_fn)
    assert len(asked) == 1 and asked[0].tolist() == [1, 2, 3]
    assert used.tolist() == [False, True, True, True, False, False, False]
    assert verdict.tolist() == [False, True, True, True, True, True, True]
    asked.clear()
    verdict, used = apply_band(logit, Band(0.2, 0.2, 0.0, 1.0, 0.0), exact_fn)  # empty band: never called
    assert not asked and not used.any() and verdict.tolist() == (logit >= 0.2).tolist()
    with pytest.raises(ValueError, match="returned"):
        apply_band(logit, band, lambda rows: np.ones(1, bool))
    s = cascade_scores(logit, np.array([1, 0, 1, 0, 0, 1, 1], bool), band)  # one FN below, one FP above the band
    assert s == {"fnr": 0.25, "accuracy": pytest.approx(5 / 7), "exact_share": pytest.approx(3 / 7), "n": 7}


# ---------------------------------------------------------------- the handler's verification through the cascade
class _Net(torch.nn.Module):
    """A detector on 1-D codes whose logit is ``z - shift``."""

    def __init__(self, shift: float = 0.0):
        super().__init__()
        self.shift = torch.nn.Parameter(torch.tensor(float(shift)), requires_grad=False)

    def forward(self, z):
        from types import SimpleNamespace

        return SimpleNamespace(logit=z[:, 0] - self.shift)


def _certified(u, shift, band, margins=(4.0, 6.0)):
    from neuralcol.handler.alm import Resolution
    from neuralcol.stages.handler import certified_handling

    z_user = torch.tensor(u, dtype=torch.float32)[:, None]
    labeled = []

    def handle(rows, margin):  # the "handler": moves each code down by the margin
        z = z_user[torch.as_tensor(rows)] - margin
        n = len(rows)
        t = torch.ones(n, dtype=torch.bool)
        return Resolution(z, t, t, t, torch.ones(n, dtype=torch.long), z[:, 0], torch.zeros(n))

    def label(z, rows=None):  # exact PD = the code itself
        labeled.append(len(z))
        return z[:, 0].double().numpy()

    res = handle(np.arange(len(u)), 3.0)
    pd_after = label(res.z)
    labeled.clear()
    out = certified_handling(_Net(shift), handle, label, z_user, res, np.full(len(u), 10.0), pd_after,
                             list(margins), 0.05, band)
    return out, sum(labeled)


def test_handler_verification_through_the_cascade():
    # first handling: z = u - 3; band [-0.5, 0.5) on a perfect detector (logit = z)
    u = [0.0, 2.8, 3.2, 4.0, 4.2, 9.0]  # z = -3 (trusted free), -0.2, 0.2 (exact), 1.0, 1.2 (trusted colliding), 6
    band = Band(-0.5, 0.5, 0.0, 1.0, 0.0)
    out, measured = _certified(u, 0.0, band)
    # decisions: 6 first results (2 exact, read), then the 4 judged colliding (0.2 exact; 1.0, 1.2, 6 trusted) at
    # margin 4: z = -0.8 (trusted free), 0, 0.2 (exact), 5 (trusted); then 0.2 and 5 at margin 6: -1.8 (trusted
    # free), 3 (trusted colliding, not better than the trusted 6: kept)
    assert out["handled_per_stage"] == [4, 2]
    assert out["kept_per_stage"] == [3, 2, 1] and out["n"] == 6
    assert out["decisions"] == 6 + 4 + 2
    assert out["exact_calls"] == 2 + 2 + 0
    assert out["exact_share"] == pytest.approx(4 / 12)
    assert out["resolved_rate"] == pytest.approx(5 / 6)  # only u = 9 (z = 6, the detector's "colliding") collides
    assert out["trusted_free_colliding"] == 0
    # labels after the first handling: 2 exact calls at margin 4, then 2 measurements for the evaluation (the two
    # results trusted free after the first handling)
    assert measured == 4
    # a detector that calls free what collides (logit = z - 1): the cascade trusts it below lo, and the evaluation
    # counts it
    out, _ = _certified([3.2, 3.3], 1.0, band, margins=(4.0,))
    assert out["trusted_free_colliding"] == 2 and out["resolved_rate"] == 0 and out["exact_calls"] == 0


# ---------------------------------------------------------------- the pipeline stage and the config
SCHEMA_TARGET = {"target_fnr", "lo", "hi", "calibration", "test", "realistic", "samples_per_s", "speedup_vs_exact"}


def test_cascade_report_schema_and_speed():
    from experiments.reporting.summary import cascade_table
    from neuralcol.stages.cascade import cascade_report, choose_bands

    rng = np.random.default_rng(1)
    y_cal = rng.random(500) < 0.3
    l_cal = rng.normal(0, 1, 500) + np.where(y_cal, 1.2, -1.2)
    bands = choose_bands(l_cal, y_cal, [0.01, 0.05])
    y_test = rng.random(300) < 0.3
    l_test = rng.normal(0, 1, 300) + np.where(y_test, 1.2, -1.2)
    m = cascade_report(bands, y_cal, 7, l_test, y_test, detector_us=2.0, exact_ms=5.0,
                       realistic=(l_test[:50], y_test[:50]))
    assert set(m) == {"calibration", "exact_ms_per_sample", "detector_us_per_sample", "targets", "detector_alone"}
    assert m["calibration"] == {"n": 500, "seed": 7, "base_rate": pytest.approx(y_cal.mean())}
    assert set(m["detector_alone"]) == {"test", "samples_per_s"} and set(m["detector_alone"]["test"]) == {"fnr",
                                                                                                         "accuracy"}
    assert m["detector_alone"]["samples_per_s"] == pytest.approx(5e5)
    for t in m["targets"]:
        assert set(t) == SCHEMA_TARGET
        assert set(t["calibration"]) == {"fnr", "accuracy", "exact_share"}
        assert set(t["test"]) == set(t["realistic"]) == {"fnr", "accuracy", "exact_share", "n"}
        assert t["realistic"]["n"] == 50 and t["test"]["n"] == 300
        cost = 2e-6 + t["test"]["exact_share"] * 5e-3
        assert t["samples_per_s"] == pytest.approx(1 / cost)
        assert t["speedup_vs_exact"] == pytest.approx(5e-3 / cost)
        assert t["test"] == cascade_scores(l_test, y_test, bands[t["target_fnr"]])
    assert m["targets"][0]["test"]["exact_share"] >= m["targets"][1]["test"]["exact_share"]
    assert cascade_report(bands, y_cal, 7, l_test, y_test, 2.0, 5.0)["targets"][0]["realistic"] is None
    lines = cascade_table(m)
    assert len(lines) == 2 + 2 + 1 and "0.01" in lines[2]


def test_cascade_settings_are_checked():
    from neuralcol.pipeline.validate import config_problems

    assert config_problems(_compose(["detector=tiny"])) == []
    problems = config_problems(_compose([
        "detector.cascade.targets=[0.01,1.5]", "detector.cascade.calibration_size=0",
        "detector.cascade.calibration_seed=${detector.test_seed}", "detector.cascade.min_accuracy=best",
        "detector.cascade.enabled=maybe", "detector.cascade.timing_samples=-1"]))
    for key in ("detector.cascade.targets=[0.01, 1.5]: must be a non-empty list of FNR targets in [0, 1)",
                "detector.cascade.calibration_size=0: must be an integer >= 1",
                "detector.cascade.calibration_seed=1000003: must differ from detector.test_seed",
                "detector.cascade.min_accuracy='best': use detector", "detector.cascade.enabled='maybe'",
                "detector.cascade.timing_samples=-1"):
        assert any(p.startswith(key) for p in problems), (key, problems)
    assert config_problems(_compose(["detector.cascade.min_accuracy=null"])) == []
    assert config_problems(_compose(["detector.cascade.min_accuracy=0.9"])) == []


# ---------------------------------------------------------------- the API on a small latent space of tubes
@pytest.fixture(scope="module")
def tube_run(tube_dataset, tmp_path_factory):
    """A TrainedRun over a quickly trained latent space of the tubes with an untrained detector (its logits route
    rows as well as any), labeled by the run's exact labeler in this process."""
    from conftest import TUBE_LATENT
    from omegaconf import OmegaConf

    from neuralcol.api import TrainedRun
    from neuralcol.data.features import dataset_features
    from neuralcol.nn.detector import build_detector
    from neuralcol.stages.autoencoder import train_or_load_latent_space
    from neuralcol.utils.config import as_dict

    cache = tmp_path_factory.mktemp("cascade_cache")
    cfg = _compose(["labeling.pool.workers=0", "labeling.pool.progress=false", f"paths.cache_dir={cache}",
                    "autoencoder=tiny", "detector=tiny", "handler.repair.enabled=false",
                    "handler.alm.max_outer=2", "handler.alm.inner_iters=5"])  # (the handler: quick, not good)
    ae = OmegaConf.merge(cfg.autoencoder, {"level1": {"epochs": 30}, "level2": {"epochs": 20}, "val_fraction": 0.25})
    space, report, _ = train_or_load_latent_space(tube_dataset, dataset_features(tube_dataset, 0), ae, TUBE_LATENT,
                                                  0, cache)
    torch.manual_seed(0)
    net = build_detector(space, as_dict(cfg.detector))
    run = TrainedRun(tmp_path_factory.mktemp("tube_run"), cfg, {"autoencoder": {"cache_key": report["cache_key"]},
                                                                 "detector": {}}, space, net, pd_unit=0.05,
                     temperature=0.1, workers=0)
    yield run
    run.close()


def _crossing(rest: np.ndarray) -> np.ndarray:
    """The rest tube with its top cap's centre pulled outside, level with the middle: its cap triangles cross the
    wall (self-intersecting)."""
    v = rest.copy()
    v[-1] = [1.0, 0.0, 1.0]
    return v


def _recording(run, monkeypatch) -> list:
    """Records the meshes the cascade's exact calls judge (in this process: the labeler's verdict, one per mesh)."""
    assert run.label_pool().workers <= 1
    lab = run.labeler
    seen, real = [], lab.verdict

    def verdict(v):
        seen.append(np.array(v, copy=True))
        return real(v)

    monkeypatch.setattr(lab, "verdict", verdict)
    return seen


def test_detect_certify_labels_the_band_rows_of_the_users_meshes(tube_run, monkeypatch):
    run = tube_run
    rest = run.space.rest_vertices.double().numpy()
    z = run.space.sample(5, generator=torch.Generator().manual_seed(1))
    meshes = np.concatenate([run.decode(z).double().numpy(), _crossing(rest)[None], rest[None]])
    assert run.label(_crossing(rest)).collides[0] and not run.label(meshes[:5]).collides.any()
    plain = run.detect(meshes)
    assert plain.exact is None and torch.equal(plain.collides, plain.logit > 0)
    logit = plain.logit.double().numpy()
    lo, hi = np.sort(logit)[2], logit[5] + 1e-3  # the crossing mesh in the band, with a few others
    band = Band(lo, hi, 0.0, 1.0, 0.0)
    monkeypatch.setattr(run, "band", lambda target, *a, **k: band)
    seen = _recording(run, monkeypatch)
    det = run.detect(meshes, certify=0.05)
    rows = np.flatnonzero(band_mask(logit, band))
    assert 5 in rows and len(rows) < len(meshes)
    assert det.exact.numpy().tolist() == band_mask(logit, band).tolist()
    assert np.array_equal(np.stack(seen), meshes[rows])  # the user's meshes themselves, not round trips
    want = logit >= hi
    want[rows] = [r == 5 for r in rows]  # the exact labels
    assert det.collides.numpy().tolist() == want.tolist()
    assert det.prob[torch.as_tensor(rows)].tolist() == [float(w) for w in want[rows]]
    outside = torch.as_tensor(~band_mask(logit, band))
    assert torch.equal(det.prob[outside], plain.prob[outside]) and torch.equal(det.logit, plain.logit)
    # codes: the band rows are decoded, then labeled
    seen.clear()
    zl = run.detect(z).logit.double().numpy()
    monkeypatch.setattr(run, "band", lambda target, *a, **k: Band(np.median(zl), np.inf, 0.0, 1.0, 0.0))
    det = run.detect(z, certify=0.05)
    rows = np.flatnonzero(zl >= np.median(zl))
    assert np.allclose(np.stack(seen), run.decode(z[torch.as_tensor(rows)]).double().numpy())
    assert det.exact.numpy().tolist() == (zl >= np.median(zl)).tolist() and not det.collides.any()


def test_band_from_the_runs_calibration_set_and_its_errors(tube_run, tmp_path):
    from neuralcol.stages.cascade import save_calibration

    run = tube_run
    path = run.run_dir / "cascade.npz"
    path.unlink(missing_ok=True)
    run._calibration = None
    with pytest.raises(UserInputError, match=r"cascade.npz: missing.*run.calibrate\(\)"):
        run.detect(run.space.sample(2), certify=0.01)
    rng = np.random.default_rng(3)
    y = rng.random(300) < 0.4
    logit = (rng.normal(0, 1, 300) + np.where(y, 1.0, -1.0)).astype(np.float32)
    save_calibration(path, logit, y, 1000033)
    run._calibration = None
    for target in (0.01, 0.13):  # any target, not only the configured ones
        # the run's settings: the pointwise floor, the FNR certified at confidence 0.9 (conf/detector/cpu.yaml)
        assert run.band(target) == choose_band(logit.astype(np.float64), y, target, "pointwise", 0.9)
        assert run.band(target, "detector") == choose_band(logit.astype(np.float64), y, target, "detector", 0.9)
    assert run.band(0.05, None).calib_exact_share == 0
    with pytest.raises(UserInputError, match="certify=1.5: target_fnr"):
        run.detect(run.space.sample(2), certify=1.5)
    # calibrate(): labels a calibration set through the run's pool and writes cascade.npz; the tubes of U(Z) never
    # self-intersect, so choosing a band from it names the problem
    assert run.calibrate(size=16, seed=5) == path
    with np.load(path) as f:
        assert f["logit"].shape == (16,) and int(f["seed"]) == 5 and not f["collides"].any()
    with pytest.raises(UserInputError, match="none of the 16 calibration samples collides"):
        run.band(0.05)
    with pytest.raises(UserInputError, match="test_seed"):
        run.calibrate(size=4, seed=int(run.cfg.detector.test_seed))
    path.unlink()
    run._calibration = None


def test_resolve_certify_verifies_the_band_rows_only(tube_run, monkeypatch):
    from neuralcol.handler.resolve import detector_logits

    run = tube_run
    z = run.space.sample(4, generator=torch.Generator().manual_seed(2))
    first = run.resolve(z, verify=False)  # the handler's first results (deterministic)
    assert first.exact is None and first.free is None and first.exact_share is None
    logit = detector_logits(run.detector, first.codes)
    band = Band(float(np.median(logit)), np.inf, 0.0, 1.0, 0.0)  # the upper half of the results verified exactly
    monkeypatch.setattr(run, "band", lambda target, *a, **k: band)
    with pytest.raises(UserInputError, match="verify=True"):
        run.resolve(z, verify=False, certify=0.05)
    out = run.resolve(z, certify=0.05)
    inside = band_mask(logit, band)
    assert 0 < inside.sum() < len(z)
    # the tubes of U(Z), handled or not, never self-intersect: the band's results are verified free, the others
    # trusted free (below lo), so nothing is handled again
    torch.testing.assert_close(out.codes, first.codes)
    assert out.exact.tolist() == inside.tolist() and out.free.all()
    assert np.isnan(out.pd_after[~inside]).all() and (out.pd_after[inside] <= 0).all()
    assert out.exact_share == pytest.approx(inside.mean())
    mesh = run.resolve(run.decode(z[:1]).double(), certify=0.05, repair=False)
    assert mesh.exact is not None and mesh.free is not None and 0 <= mesh.exact_share <= 1
    assert (np.isnan(mesh.pd_after) | mesh.exact).all()


def test_cascade_stage_times_the_exact_path(tube_run):
    """The stage's report on a test set and a realistic set, with the exact path timed here (one thread, torch's
    thread count restored), and the calibration file round trip."""
    from types import SimpleNamespace

    from neuralcol.stages.cascade import cascade_stage, load_calibration, save_calibration

    run = tube_run
    z = run.space.sample(40, generator=torch.Generator().manual_seed(4)).numpy()
    logit = run.detect(z).logit.double().numpy()
    y = logit > np.median(logit)  # (labels made up: the stage reads them, it does not label the test set)
    bands = {0.0: choose_band(logit, y, 0.0), 0.25: choose_band(logit, y, 0.25, None)}
    threads = torch.get_num_threads()
    m = cascade_stage(run.detector, run.space, run.labeler, SimpleNamespace(z=z, collides=y), bands, y,
                      {"cascade": {"calibration_seed": 11, "timing_samples": 3}}, detector_us=1.5,
                      realistic_arrays={"logit": logit, "pd": np.where(y, 1.0, -1.0), "clear": np.arange(40) < 30})
    assert torch.get_num_threads() == threads
    assert m["exact_ms_per_sample"] > 0 and m["detector_us_per_sample"] == 1.5
    assert m["calibration"]["seed"] == 11 and [t["target_fnr"] for t in m["targets"]] == [0.0, 0.25]
    t0, t1 = m["targets"]
    assert t0["test"]["fnr"] == 0 and t0["test"]["accuracy"] == 1  # the calibration set itself
    assert t1["test"]["exact_share"] == 0 and t1["speedup_vs_exact"] == pytest.approx(
        m["exact_ms_per_sample"] * 1e3 / 1.5)
    assert t0["realistic"]["n"] == 30
    save_calibration(run.run_dir / "c.npz", logit, y, 11)
    back = load_calibration(run.run_dir / "c.npz")
    np.testing.assert_array_equal(back[1], y)
    np.testing.assert_allclose(back[0], logit.astype(np.float32))


def test_cascade_table_from_saved_arrays(tmp_path, capsys):
    """experiments.cascade_table: bands and test scores from a run's saved arrays, priced with its timings."""
    import json

    from experiments.cascade_table import cascade_rows, main
    from neuralcol.metrics.cascade import cascade_scores, choose_band

    rng = np.random.default_rng(3)
    y_cal, y_test = rng.random(400) < 0.3, rng.random(600) < 0.3
    l_cal, l_test = rng.normal(size=400) + 2 * y_cal - 1, rng.normal(size=600) + 2 * y_test - 1
    np.savez(tmp_path / "cascade.npz", logit=l_cal, collides=y_cal, seed=1)
    np.savez(tmp_path / "test_predictions.npz", logit=l_test, collides=y_test)
    (tmp_path / "metrics.json").write_text(json.dumps({"cascade": {"exact_ms_per_sample": 10.0,
                                                                   "detector_us_per_sample": 5.0}}))
    rows = cascade_rows(tmp_path, [0.02])
    assert [r["floor"] for r in rows] == ["pointwise", "detector"]
    for r in rows:
        s = cascade_scores(l_test, y_test, choose_band(l_cal, y_cal, 0.02, r["floor"]))
        assert (r["fnr"], r["accuracy"], r["exact_share"]) == (s["fnr"], s["accuracy"], s["exact_share"])
        assert r["samples_per_s"] == pytest.approx(1 / (5e-6 + s["exact_share"] * 1e-2))
    main([str(tmp_path), "--targets", "0.02"])
    assert "| pointwise | 0.02 |" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main([str(tmp_path / "nothing")])


def test_allowed_misses_clopper_pearson_and_coverage():
    """The confidence level certifies the FNR on fresh samples: over many calibration draws, the true FNR of the
    chosen lo exceeds the target in at most about 1 - confidence of them (without it, in about half)."""
    from scipy.stats import beta, norm

    from neuralcol.metrics.cascade import allowed_misses

    assert allowed_misses(320, 0.01) == 3
    assert allowed_misses(320, 0.01, 0.9) == 0  # U(0) = 0.0072 <= 0.01 < U(1) = 0.0121
    assert beta.ppf(0.9, 1, 320) <= 0.01 < beta.ppf(0.9, 2, 319)
    assert allowed_misses(100, 0.01, 0.9) == 0  # too few colliding samples to certify: the strictest lo
    assert allowed_misses(5000, 0.05, 0.9) == max(k for k in range(5000) if beta.ppf(0.9, k + 1, 5000 - k) <= 0.05)
    with pytest.raises(ValueError, match="confidence"):
        allowed_misses(10, 0.1, 1.0)
    rng = np.random.default_rng(0)
    over = {None: 0, 0.9: 0}
    draws = 300
    for _ in range(draws):
        y = rng.random(2000) < 0.3
        logit = rng.normal(size=2000) + np.where(y, 1.5, -1.5)
        for conf in over:
            band = choose_band(logit, y, 0.02, None, conf)
            over[conf] += norm.cdf(band.lo - 1.5) > 0.02  # the true FNR of lo for colliding logits ~ N(1.5, 1)
    assert over[0.9] / draws <= 0.15 and over[None] / draws >= 0.3

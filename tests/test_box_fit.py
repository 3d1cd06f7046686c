"""box_fit: the paper's box scaled about its centre until a probe of U(Z) lies in the band."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from neuralcol.stages.box_fit import band_distance, check_ladder, fit_box, fitted_key, fitted_space, scaled_box

SHRINK, GROW = [0.9, 0.8, 0.7, 0.6, 0.5], [1.25, 1.5, 2.0]


def _space(lo=(-1.0, 2.0), hi=(3.0, 4.0)):
    return SimpleNamespace(box_lo=torch.tensor(lo), box_hi=torch.tensor(hi))


def _probe_by_width(share_of_factor):
    """A probe whose colliding share is a known function of the box's scale (width of entry 0 against 4.0)."""
    calls = []

    def probe(space):
        factor = round(float(space.box_hi[0] - space.box_lo[0]) / 4.0, 6)
        calls.append(factor)
        return {"n": 10, "n_labeled": 10, "collision_share": share_of_factor(factor)}

    return probe, calls


def test_scaled_box_keeps_the_centre_and_scales_the_width():
    lo, hi = torch.tensor([-1.0, 2.0]), torch.tensor([3.0, 4.0])
    slo, shi = scaled_box(lo, hi, 0.5)
    assert torch.allclose((slo + shi) / 2, (lo + hi) / 2)
    assert torch.allclose(shi - slo, (hi - lo) / 2)
    assert torch.equal(torch.stack(scaled_box(lo, hi, 1.0)), torch.stack((lo, hi)))


def test_band_distance():
    assert band_distance(0.3, [0.1, 0.55]) == 0
    assert band_distance(0.65, [0.1, 0.55]) == pytest.approx(0.10)
    assert band_distance(0.02, [0.1, 0.55]) == pytest.approx(0.08)
    assert band_distance(None, [0.1, 0.55]) == float("inf")


def test_a_box_in_the_band_is_untouched_and_probed_once():
    space = _space()
    probe, calls = _probe_by_width(lambda f: 0.3)
    fit = fit_box(space, probe, [0.1, 0.55], SHRINK, GROW)
    assert fit["factor"] == 1.0 and fit["in_band"] and calls == [1.0]
    assert torch.equal(space.box_lo, torch.tensor([-1.0, 2.0])) and torch.equal(space.box_hi, torch.tensor([3.0, 4.0]))
    assert fitted_key("abc", fit["factor"]) == "abc"


def test_too_many_collisions_shrink_to_the_first_factor_in_the_band():
    space = _space()
    probe, calls = _probe_by_width(lambda f: f * 0.7)  # 0.70 at the paper's box, 0.49 at 0.7
    fit = fit_box(space, probe, [0.1, 0.55], SHRINK, GROW)
    assert calls == [1.0, 0.9, 0.8, 0.7] and fit["factor"] == 0.7 and fit["in_band"]
    assert [t["factor"] for t in fit["trials"]] == calls
    # the space itself keeps its box; the fitted space is a new object with the scaled one
    assert torch.equal(space.box_lo, torch.tensor([-1.0, 2.0])) and torch.equal(space.box_hi, torch.tensor([3.0, 4.0]))
    fitted = fitted_space(space, fit["factor"])
    lo, hi = scaled_box(torch.tensor([-1.0, 2.0]), torch.tensor([3.0, 4.0]), 0.7)
    assert fitted is not space and torch.allclose(fitted.box_lo, lo) and torch.allclose(fitted.box_hi, hi)
    assert fitted_key("abc", 0.7) == "abc-box0.7"


def test_too_few_collisions_grow_the_box():
    probe, calls = _probe_by_width(lambda f: 0.06 * f * f)  # 0.06, 0.094, 0.135
    fit = fit_box(_space(), probe, [0.1, 0.55], SHRINK, GROW)
    assert calls == [1.0, 1.25, 1.5] and fit["factor"] == 1.5


def test_a_share_that_crosses_the_band_stops_and_takes_the_nearest():
    probe, calls = _probe_by_width(lambda f: 0.9 if f > 0.85 else 0.02)  # jumps over [0.1, 0.55]
    fit = fit_box(_space(), probe, [0.1, 0.55], SHRINK, GROW)
    assert calls == [1.0, 0.9, 0.8]  # 0.8 is below the band: the rest of the ladder moves further away
    assert fit["factor"] == 0.8 and not fit["in_band"]  # 0.08 below the band is nearer than 0.35 above it


def test_no_factor_reaches_the_band():
    probe, calls = _probe_by_width(lambda f: 1.0)  # every box collides (the skirt's bilevel space)
    fit = fit_box(_space(), probe, [0.1, 0.55], SHRINK, GROW)
    assert calls == [1.0, *SHRINK] and not fit["in_band"]
    assert fit["factor"] == 1.0  # all equally far: the paper's box, and box_check then stops the run


@pytest.mark.parametrize("band, shrink, grow, setting", [
    ([0.6, 0.5], SHRINK, GROW, "box_fit.band"), ([0.1], SHRINK, GROW, "box_fit.band"),
    ([0.1, 0.5], [1.1], GROW, "box_fit.shrink"), ([0.1, 0.5], SHRINK, [0.9], "box_fit.grow")])
def test_bad_settings_name_themselves(band, shrink, grow, setting):
    with pytest.raises(ValueError, match=setting):
        check_ladder(band, shrink, grow)


def test_run_context_fits_caches_and_saves_the_fitted_space(tmp_path, scape_dir):
    """On SCAPE's PCA space (fit in milliseconds): a band below the paper box's share makes it shrink; the fitted
    space is a new object (the paper box's space keeps its box), saved under its own key, and loads with the fitted
    box; a second context reads the cached fit and labels nothing."""
    from hydra import compose, initialize_config_dir

    from neuralcol.nn.latent_space import LatentSpace
    from neuralcol.pipeline import RunContext
    from neuralcol.stages.box_check import box_stage

    overrides = ["dataset=scape", "autoencoder=pca", "detector=tiny", f"paths.data_dir={scape_dir.parent}",
                 f"paths.cache_dir={tmp_path}/cache", "labeling.pool.workers=0", "labeling.pool.progress=false",
                 "box_fit.enabled=true", "box_fit.band=[0.0,0.3]", "box_check.n_probe=32"]
    with initialize_config_dir(config_dir=str(Path(__file__).resolve().parents[1] / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides, return_hydra_config=False)
    ctx = RunContext(cfg)
    key0 = ctx.latent_space().report["cache_key"]
    box0 = (ctx.space.box_lo.clone(), ctx.space.box_hi.clone())
    labeler = ctx.sample_labeler()
    with ctx.pool(labeler) as pool:
        fitted = ctx.fit_box(pool, labeler)
        assert ctx.fit_box(pool, labeler) is fitted  # fitted once per context
        fit = fitted.report["box_fit"]
        probe = box_stage(fitted.space, {}, pool, cfg, fit)
    shares = [t["collision_share"] for t in fit["trials"]]
    assert shares[0] > 0.3 and fit["factor"] < 1.0, fit  # SCAPE's vertex-PCA box: ~65 % collide
    chosen = next(t for t in fit["trials"] if t["factor"] == fit["factor"])
    assert probe["space"]["collision_share"] == chosen["collision_share"]  # the fit's probe, not labeled again
    key = fitted.report["cache_key"]
    assert key == f"{key0}-box{fit['factor']:g}" and ctx.latent_space().report["cache_key"] == key0
    lo, hi = scaled_box(*box0, fit["factor"])
    assert torch.allclose(fitted.space.box_lo, lo) and torch.allclose(fitted.space.box_hi, hi)
    assert fitted.space is not ctx.space and torch.equal(ctx.space.box_lo, box0[0])  # the paper box is untouched
    assert torch.equal(ctx.space.box_hi, box0[1]) and ctx.oracle(pool, fitted).space is fitted.space
    assert ctx.samples_dir(labeler, fitted).name != ctx.samples_dir(labeler).name
    saved = LatentSpace.load(ctx.cache.latent_space(key))
    assert torch.allclose(saved.box_lo, lo) and torch.allclose(saved.box_hi, hi)
    assert saved.meta["box_fit"] == {"factor": fit["factor"], "from": key0}
    cached = json.loads(next(ctx.samples_dir(labeler).parent.glob("*/box_fit_*.json")).read_text())
    assert cached["factor"] == fit["factor"] and cached["settings"]["n_probe"] == 32

    again = RunContext(cfg)
    with again.pool(labeler) as pool:
        pool.label_report = None  # labeling anything now would raise: the fit must come from the cache
        fitted2 = again.fit_box(pool, labeler)
    assert fitted2.report["box_fit"]["factor"] == fit["factor"] and fitted2.report["cache_key"] == key
    assert torch.allclose(fitted2.space.box_lo, lo)

"""neuralcol.load_run (the finished-run API), its errors, the README's first Python example, and the export of
the decoder and detector (TorchScript, ONNX) checked against the live modules."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from neuralcol.errors import UserInputError

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """One tiny finished run (procedural hand, 24 poses, tiny autoencoder and detector; ~30 s), shared."""
    from experiments.run import run

    tmp = tmp_path_factory.mktemp("api")
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(config_name="config", overrides=[
            "dataset=proc_hand", "dataset.source.n_poses=24", f"paths.cache_dir={tmp}/cache", "n_example_meshes=0",
            "autoencoder=tiny", "detector=tiny", "realistic=tiny", "speed_accuracy.enabled=false",
            "handler.n_inputs=0", "labeling.pool.workers=0",
            "labeling.pool.progress=false"])
    run(cfg, tmp / "run")
    (tmp / "run" / ".hydra").mkdir()
    OmegaConf.save(cfg, tmp / "run" / ".hydra" / "config.yaml")
    return tmp / "run"


@pytest.fixture(scope="module")
def trained(run_dir):
    import neuralcol

    with neuralcol.load_run(run_dir) as run:
        yield run


def _codes(run, n: int, seed: int) -> torch.Tensor:
    return run.space.sample(n, generator=torch.Generator().manual_seed(seed))


def test_detect_encode_decode_label(trained):
    from neuralcol.collision.labeler import ExactLabeler
    from neuralcol.nn.detector import smooth_max

    z = _codes(trained, 6, 0)
    det = trained.detect(z, batch_size=4)  # two batches
    out = trained.detector(z)
    torch.testing.assert_close(det.prob, out.prob)  # (batches of 4 and 2 vs 6: float rounding)
    torch.testing.assert_close(det.pd, smooth_max(out.s, trained.temperature) * trained.pd_unit)
    assert det.pd_sub.shape == (6, trained.space.n_parts)
    verts = trained.decode(z)
    assert verts.shape == (6, trained.n_vertices, 3)
    torch.testing.assert_close(trained.detect(verts, inputs="latent").prob,
                               trained.detector(trained.encode(verts)).prob)
    one = trained.detect(verts[0].numpy())  # one (V, 3) numpy mesh
    assert one.prob.shape == (1,)
    bad = verts.clone()
    bad[1, 3, 0] = float("nan")
    with pytest.raises(UserInputError, match="non-finite coordinates"):  # checked on the codes, named by the mesh
        trained.detect(bad)
    # outside_box: inside Z for codes from U(Z); an entry past the box's edge by a hair flags the row only
    assert not trained.detect(trained.space.sample(8)).outside_box.any()
    lo, hi = trained.space.box_lo, trained.space.box_hi
    edge = torch.stack([lo, hi, lo.clone(), hi.clone()])
    edge[2, 0] -= 1e-3 * (hi[0] - lo[0])
    edge[3, -1] += 1e-3 * (hi[-1] - lo[-1])
    assert trained.detect(edge).outside_box.tolist() == [False, False, True, True]
    assert torch.equal(trained.detect(verts).outside_box, trained.space.outside_box(trained.encode(verts)))
    labels = trained.label(verts)
    ref = ExactLabeler(trained.faces, trained.space.rest_vertices.numpy(), partition=trained.space.partition.numpy(),
                       **{k: v for k, v in OmegaConf.to_container(trained.cfg.labeling.labeler).items()
                          if not k.startswith("_")})
    np.testing.assert_array_equal(labels.pd, [ref.label(v).pd for v in verts.double().numpy()])


def test_the_separate_mesh_detector_options_say_it_was_folded(trained):
    """The separate mesh detector was folded into the run's one detector: an old caller's inputs='mesh' /
    'auto' and constraint='mesh' get one line saying so and how to train it; 'latent' (what they always meant by
    default) still works."""
    z = _codes(trained, 3, 2)
    verts = trained.decode(z)
    folded = r"the separate mesh detector \(mesh_detector.pt\) was folded into the run's detector: " \
             r"train with detector.inputs=code_and_mesh \(the default\)"
    for inputs in ("mesh", "auto"):
        with pytest.raises(UserInputError, match=f"inputs='{inputs}': {folded}") as e:
            trained.detect(verts, inputs=inputs)
        assert "\n" not in str(e.value)
    with pytest.raises(UserInputError, match=f"constraint='mesh': {folded}"):
        trained.resolve(verts[:1], verify=False, constraint="mesh")
    torch.testing.assert_close(trained.detect(verts, inputs="latent").logit, trained.detect(verts).logit)
    with pytest.raises(UserInputError, match="inputs='pixels': the option was removed \\(the run's one detector"):
        trained.detect(z, inputs="pixels")


def test_a_stray_mesh_detector_file_is_ignored(run_dir, trained, tmp_path):
    """An older run directory may still hold mesh_detector.pt: load_run never reads it (here it is
    not even a torch file) and the run answers as without it."""
    import neuralcol

    old = tmp_path / "old_run"
    shutil.copytree(run_dir, old)
    (old / "mesh_detector.pt").write_bytes(b"not a torch file")
    z = _codes(trained, 4, 5)
    with neuralcol.load_run(old) as again:
        assert not hasattr(again, "mesh_detector")
        torch.testing.assert_close(again.detect(z).logit, trained.detect(z).logit)


def test_detect_fast_forms(trained):
    """detect(..., fast=...): the compiled float32 copy agrees with the network, bfloat16 closely; bad names are
    refused. Without a C++ compiler only the error path is checked."""
    z = _codes(trained, 40, 3)
    ref = trained.detect(z)
    with pytest.raises(UserInputError, match="fast='float16'"):
        trained.detect(z, fast="float16")
    if not any(shutil.which(c) for c in ("c++", "g++", "clang++")):
        pytest.skip("torch.compile on the CPU needs a C++ compiler")
    f32 = trained.detect(z, fast="float32")
    torch.testing.assert_close(f32.prob, ref.prob, rtol=0, atol=1e-5)
    torch.testing.assert_close(f32.pd, ref.pd, rtol=1e-4, atol=1e-4)
    bf = trained.detect(z, batch_size=16, fast="bfloat16")
    assert float((bf.prob - ref.prob).abs().max()) < 0.05
    checked = trained.detect(z, fast="bfloat16_checked")
    assert torch.equal(checked.prob > 0.5, ref.prob > 0.5)
    assert set(trained._fast) == {"float32", "bfloat16", "bfloat16_checked"}  # built once, kept


def test_resolve_latent_and_cartesian(trained):
    """Two colliding meshes through the neural path (no repair) and a free one, which comes back as given."""
    z = _codes(trained, 200, 7)
    hit = trained.label(trained.decode(z)).collides
    z = z[torch.as_tensor(np.concatenate([np.flatnonzero(hit)[:2], np.flatnonzero(~hit)[:1]]))]
    verts = trained.decode(z)
    res = trained.resolve(verts, margins=[4.0], repair=False)
    assert res.vertices.shape == (3, trained.n_vertices, 3) and res.codes.shape == (3, trained.dim)
    np.testing.assert_array_equal(res.pd_input, trained.label(verts).pd)
    # the free input comes back as given, without encoder or handler (tests/test_resolve_free.py)
    assert res.untouched.tolist() == [False, False, True] and np.isnan(res.margin[2])
    assert torch.equal(res.vertices[2], verts[2].double()) and torch.isnan(res.codes_before[2]).all()
    h = slice(0, 2)
    torch.testing.assert_close(res.codes_before[h], trained.encode(verts[h]))
    np.testing.assert_array_equal(res.pd_before[h], trained.label(trained.decode(res.codes_before[h])).pd)
    finite = np.isfinite(res.pd_after) & ~res.untouched
    keep = torch.as_tensor(finite)
    np.testing.assert_array_equal(res.pd_after[finite], trained.label(res.vertices[finite].double()).pd)
    assert set(res.margin[h]) <= {3.0, 4.0}
    # a mesh comes back as the user's mesh, corrected: input + (D(Z) - D(Z_user)), median shift removed
    from neuralcol.handler.resolve import transfer_displacement

    torch.testing.assert_close(res.decoded[h], trained.decode(res.codes[h]))
    expect = transfer_displacement(verts[h].double(), trained.decode(res.codes_before[h]).double(),
                                   res.decoded[h].double())
    torch.testing.assert_close(res.vertices[h][keep[h]], expect[keep[h]])
    moved = (res.vertices - verts.double()).norm(dim=-1)
    np.testing.assert_allclose(res.displacement_max, moved.max(1).values.numpy(), rtol=1e-4, atol=1e-6)
    assert res.diagonal == pytest.approx(float(np.linalg.norm(np.ptp(trained.space.rest_vertices.numpy(), 0))))
    # detector-guided: the handler lowers the detector's logit (this tiny detector cannot reach -margin)
    assert (trained.detect(res.codes[keep]).logit < trained.detect(res.codes_before[keep]).logit).all()
    codes_only = trained.resolve(res.codes_before[h], verify=False)
    assert np.isnan(codes_only.pd_input).all() and (codes_only.margin == 3.0).all()
    assert codes_only.untouched is None
    cart = trained.resolve(verts[:1], objective="cartesian", verify=False, subset=[0, 1, 2])
    assert cart.vertices.shape == (1, trained.n_vertices, 3)
    with pytest.raises(UserInputError, match="needs meshes"):
        trained.resolve(z[:1], objective="cartesian")
    with pytest.raises(UserInputError, match="objective='nearest'"):
        trained.resolve(z[:1], objective="nearest")
    with pytest.raises(UserInputError, match=r"codes have shape \(2, 5\)"):
        trained.detect(torch.zeros(2, 5))


class CallsEverythingFree(torch.nn.Module):
    """A detector that calls every code free: the handler leaves each input alone, so a colliding input comes
    back colliding and only the contact repair can free it."""

    def __init__(self):
        super().__init__()
        self.bias = torch.nn.Parameter(torch.tensor(-10.0))

    def forward(self, z):
        from types import SimpleNamespace

        return SimpleNamespace(logit=self.bias.expand(len(z)) + 0 * z.sum(-1))


def test_resolve_with_contact_repair(trained, monkeypatch):
    """repair=True: returned meshes the exact labeler still finds penetrating after verification get the contact
    repair; those it frees come back free by the exact label (margin NaN, repaired True), the rest as without."""
    z = _codes(trained, 200, 7)
    verts = trained.decode(z)
    hit = np.flatnonzero(trained.label(verts).collides)[:3]
    assert len(hit) >= 2  # deterministic: the tiny run's box holds colliding codes
    verts = verts[torch.as_tensor(hit)].double()
    monkeypatch.setattr(trained, "detector", CallsEverythingFree())
    plain = trained.resolve(verts, margins=[4.0], repair=False)
    assert (plain.pd_after > 0).all()  # (nearly) left alone: still colliding
    assert plain.repaired is not None and not plain.repaired.any()
    fixed = trained.resolve(verts, margins=[4.0], repair=True)
    assert fixed.repaired.all() and (fixed.pd_after <= 0).all()
    np.testing.assert_array_equal(fixed.pd_after, trained.label(fixed.vertices).pd)
    assert np.isnan(fixed.margin).all()
    moved = (fixed.vertices - verts).norm(dim=-1)
    near = (plain.vertices - verts).norm(dim=-1)
    assert (np.median((moved - near).abs().numpy(), axis=1) < 1e-3 * fixed.diagonal).all()  # the rest kept
    np.testing.assert_allclose(fixed.displacement_max, moved.max(1).values.numpy())
    assert not trained.resolve(verts[:1], verify=False, repair=True).repaired.any()  # needs verify


def test_resolve_repair_first(trained, monkeypatch):
    """handler.repair.first: colliding inputs are repaired directly, and that mesh is kept wherever it is free."""
    from omegaconf import OmegaConf

    from neuralcol.repair.contact import outward_sign
    from neuralcol.repair.meshes import repair_meshes
    from neuralcol.repair.settings import RepairSettings

    z = _codes(trained, 200, 7)
    verts = trained.decode(z)
    verts = verts[torch.as_tensor(np.flatnonzero(trained.label(verts).collides)[:3])].double()
    cfg = OmegaConf.create(OmegaConf.to_container(trained.cfg))
    cfg.handler.repair.first = True
    cfg.handler.repair.cap_steps = 0  # the repair's own mesh, not capped
    monkeypatch.setattr(trained, "cfg", cfg)
    res = trained.resolve(verts, margins=[4.0])
    rest = trained.space.rest_vertices.numpy()
    s = RepairSettings(**{k: v for k, v in OmegaConf.to_container(cfg.handler.repair).items()})
    direct, _, _ = repair_meshes(verts.numpy(), trained.faces, trained.labeler, s, trained.labeler.eps,
                                 trained.diagonal, outward_sign(trained.faces, rest))
    free = trained.label(direct).pd <= 0
    assert free.any()
    assert res.repaired[free].all() and (res.pd_after[free] <= 0).all()
    np.testing.assert_array_equal(res.vertices[torch.as_tensor(free)].numpy(), direct[free])
    # what the first repair frees skips the neural handler (resolve's skip_freed): the input's code comes back
    np.testing.assert_array_equal(res.codes[torch.as_tensor(free)].cpu().numpy(),
                                  res.codes_before[torch.as_tensor(free)].cpu().numpy())
    assert torch.isnan(res.decoded[torch.as_tensor(free)]).all()
    assert np.isfinite(res.pd_after).all()


def test_resolve_shrinks_the_neural_correction(trained, monkeypatch):
    """handler.repair.shrink_steps: where the neural path frees an input, the correction is shrunk to the smallest
    share from which the repair still frees it; kept only where it moves less, free by the exact label."""
    from omegaconf import OmegaConf

    z = _codes(trained, 200, 7)
    verts = trained.decode(z)
    verts = verts[torch.as_tensor(np.flatnonzero(trained.label(verts).collides)[:6])].double()
    cfg = OmegaConf.create(OmegaConf.to_container(trained.cfg))
    cfg.handler.repair.first = False  # every input takes the neural path
    cfg.handler.repair.cap_steps = 0  # the shrink alone
    monkeypatch.setattr(trained, "cfg", cfg)
    plain = trained.resolve(verts, margins=[4.0])
    assert np.isnan(plain.shrink).all()  # off by default
    cfg.handler.repair.shrink_steps = 4
    res = trained.resolve(verts, margins=[4.0])
    tried = np.isfinite(res.shrink)
    np.testing.assert_array_equal(tried, (plain.pd_after <= 0) & (plain.pd_input > 0))
    shrunk = tried & (res.shrink < 1)
    assert shrunk.any()  # deterministic: the tiny run frees these inputs with more than it needs
    assert (res.displacement_max[shrunk] < plain.displacement_max[shrunk]).all()
    assert (res.pd_after[shrunk] <= 0).all() and res.repaired[shrunk].all()
    np.testing.assert_array_equal(res.pd_after, trained.label(res.vertices).pd)
    same = torch.as_tensor(~shrunk)
    np.testing.assert_array_equal(res.vertices[same].cpu().numpy(), plain.vertices[same].cpu().numpy())


def test_resolve_caps_the_displacement(trained, monkeypatch):
    """handler.repair.cap_steps: every colliding input returned free has its vertex moves clipped at the smallest cap
    the exact label still calls free; never a larger move, free by the exact label, the rest unchanged."""
    from omegaconf import OmegaConf

    z = _codes(trained, 200, 7)
    verts = trained.decode(z)
    verts = verts[torch.as_tensor(np.flatnonzero(trained.label(verts).collides)[:6])].double()
    cfg = OmegaConf.create(OmegaConf.to_container(trained.cfg))
    monkeypatch.setattr(trained, "cfg", cfg)
    for first in (True, False):  # the repair-first path and the neural one
        cfg.handler.repair.first = first
        cfg.handler.repair.cap_steps = 0
        plain = trained.resolve(verts, margins=[4.0])
        assert np.isnan(plain.cap).all()
        cfg.handler.repair.cap_steps = 5
        res = trained.resolve(verts, margins=[4.0])
        np.testing.assert_array_equal(np.isfinite(res.cap), plain.pd_after <= 0)
        clipped = res.cap < 1
        assert clipped.any()  # deterministic: the tiny run's results move more than they need somewhere
        assert (res.displacement_max[clipped] < plain.displacement_max[clipped]).all()
        np.testing.assert_allclose(res.displacement_max[clipped],
                                   res.cap[clipped] * plain.displacement_max[clipped], rtol=1e-9)
        np.testing.assert_array_equal(res.pd_after, trained.label(res.vertices).pd)
        assert (res.pd_after[clipped] <= 0).all()
        same = torch.as_tensor(~clipped)
        np.testing.assert_array_equal(res.vertices[same].cpu().numpy(), plain.vertices[same].cpu().numpy())


def test_load_run_errors_name_what_is_missing(run_dir, tmp_path):
    import neuralcol

    with pytest.raises(UserInputError, match="no such directory"):
        neuralcol.load_run(tmp_path / "nowhere")
    (tmp_path / "foreign").mkdir()
    with pytest.raises(UserInputError, match=r"config.yaml: missing; .* is not the output directory"):
        neuralcol.load_run(tmp_path / "foreign")
    unfinished = tmp_path / "unfinished"
    shutil.copytree(run_dir, unfinished)
    (unfinished / "metrics.json").unlink()
    with pytest.raises(UserInputError, match=r"metrics.json: missing .*finish it by running its command again "
                                             r"with hydra.run.dir="):
        neuralcol.load_run(unfinished)
    (unfinished / "metrics.json").write_text(json.dumps({"autoencoder": {"cache_key": "0"}, "detector": {}}))
    with pytest.raises(UserInputError, match="latent space is not in the cache"):
        neuralcol.load_run(unfinished)
    (unfinished / ".hydra" / "config.yaml").write_text("seed: 0\n")
    with pytest.raises(UserInputError, match="not a neuralcol run configuration"):
        neuralcol.load_run(unfinished)


def test_readme_first_python_example(run_dir, trained, tmp_path, monkeypatch, capsys):
    """The README's first ```python block, run as written; only its run directory and mesh path are replaced."""
    import neuralcol

    code = re.search(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    assert len(code.strip().splitlines()) < 10
    mesh = tmp_path / "8.obj"
    neuralcol.write_mesh(mesh, trained.decode(_codes(trained, 1, 2))[0], trained.faces)
    for placeholder, value in (('"outputs/my_run"', repr(str(run_dir))), ('"data/scape/8.obj"', repr(str(mesh)))):
        assert placeholder in code
        code = code.replace(placeholder, value)
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README.md", "exec"), {})
    assert re.match(r"p = [01]\.\d{3}, exact PD -?\d", capsys.readouterr().out)
    v, f = neuralcol.read_mesh(tmp_path / "8_resolved.obj")
    assert v.shape == (trained.n_vertices, 3) and np.array_equal(f, trained.faces)


def test_handle_cli_on_a_mesh(run_dir, trained, tmp_path, capsys):
    from experiments.handle import main
    from neuralcol import write_mesh

    write_mesh(tmp_path / "pose.obj", trained.decode(_codes(trained, 1, 3))[0], trained.faces)
    main([str(run_dir), str(tmp_path / "pose.obj"), "--out", str(tmp_path / "out"), "--margins", "4"])
    lines = capsys.readouterr().out.strip().splitlines()
    assert "PD result" in lines[0] and lines[-1].startswith("pose ")
    assert (tmp_path / "out" / "pose_resolved.obj").is_file()


def test_resolve_sequence_and_the_cli_on_a_folder_of_frames(run_dir, trained, tmp_path, capsys):
    """A motion from a free decoded mesh into a colliding one and back: resolve_sequence frees at least what
    resolving each frame alone frees, keeps the correction's frame-to-frame change within its rate where it
    freed, and the CLI takes the frames as a folder (--sequence)."""
    from experiments.handle import main
    from neuralcol import write_mesh

    z = _codes(trained, 200, 7)
    verts = trained.decode(z).double()
    hit = trained.label(verts).collides
    a, b = int(np.flatnonzero(~hit)[0]), int(np.flatnonzero(hit)[0])
    t = torch.cat([torch.linspace(0, 1, 4), torch.linspace(1, 0, 4)[1:]]).double()[:, None, None]
    frames = (1 - t) * verts[a] + t * verts[b]
    seq = trained.resolve_sequence(frames, progress=False, margins=[4.0])
    alone = trained.resolve(frames, margins=[4.0])
    assert seq.vertices.shape == tuple(frames.shape) and len(seq.correction_jump) == len(frames) - 1
    assert (~seq.collides).sum() >= (np.nan_to_num(alone.pd_after, nan=1.0) <= 0).sum()
    np.testing.assert_array_equal(seq.collides, trained.label(seq.vertices).collides)
    assert seq.rate > 0 and np.isfinite(seq.jump_ratio)
    assert not seq.resolved[0]  # the free first frame is left alone
    np.testing.assert_array_equal(seq.vertices[0], frames[0].numpy())
    with pytest.raises(UserInputError, match="at least 2"):
        trained.resolve_sequence(frames[:1])
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, f in enumerate(frames[:3]):
        write_mesh(folder / f"f{i:02d}.obj", f.numpy(), trained.faces)
    main([str(run_dir), str(folder), "--sequence", "--out", str(tmp_path / "out"), "--margins", "4"])
    out = capsys.readouterr()
    assert "correction change" in out.out and "ratio" in out.err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f"f{i:02d}_resolved.obj" for i in range(3)]


def _live(trained, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    det = trained.detect(z)
    return trained.decode(z), det.prob, det.pd


@pytest.fixture(scope="module")
def fresh_codes(trained) -> torch.Tensor:
    """Codes the export never saw, in a batch size it was not traced with, some outside the box."""
    z = _codes(trained, 7, 11)
    z[-1] = trained.space.box_hi + 0.1 * (trained.space.box_hi - trained.space.box_lo)
    return z


def test_export_torchscript_round_trip(run_dir, trained, fresh_codes, tmp_path):
    from experiments.export import main

    main([str(run_dir), "--format", "torchscript", "--out", str(tmp_path)])
    doc = json.loads((tmp_path / "manifest.json").read_text())
    assert doc["decoder"]["output"] == "vertices" and doc["sizes"]["latent_dim"] == trained.dim
    assert np.array_equal(np.load(tmp_path / "topology.npz")["faces"], trained.faces)
    decoder, detector = torch.jit.load(str(tmp_path / "decoder.pt")), torch.jit.load(str(tmp_path / "detector.pt"))
    verts, prob, pd = _live(trained, fresh_codes)
    with torch.no_grad():
        torch.testing.assert_close(decoder(fresh_codes), verts, rtol=0, atol=1e-5)
        got_prob, got_pd = detector(fresh_codes)
    torch.testing.assert_close(got_prob, prob, rtol=0, atol=1e-5)
    torch.testing.assert_close(got_pd, pd, rtol=0, atol=1e-5)


def test_export_onnx_round_trip(run_dir, trained, fresh_codes, tmp_path):
    pytest.importorskip("onnx", reason='ONNX export needs onnx: pip install -e ".[export]"')
    ort = pytest.importorskip("onnxruntime", reason='the ONNX check needs onnxruntime: pip install -e ".[export]"')
    from experiments.export import main

    main([str(run_dir), "--format", "onnx", "--out", str(tmp_path)])
    doc = json.loads((tmp_path / "manifest.json").read_text())
    assert doc["files"] == {"decoder": "decoder.onnx", "detector": "detector.onnx", "topology": "topology.npz"}
    verts, prob, pd = _live(trained, fresh_codes)
    feed = {"codes": fresh_codes.numpy()}
    (got_verts,) = ort.InferenceSession(str(tmp_path / "decoder.onnx")).run(None, feed)
    got_prob, got_pd = ort.InferenceSession(str(tmp_path / "detector.onnx")).run(["prob", "pd"], feed)
    np.testing.assert_allclose(got_verts, verts.numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(got_prob, prob.numpy(), rtol=0, atol=1e-5)
    np.testing.assert_allclose(got_pd, pd.numpy(), rtol=0, atol=1e-5)


def test_export_features_decoder_above_the_dense_limit(run_dir, trained, fresh_codes, tmp_path):
    """Above --max-dense-vertices the decoder outputs the raw ACAP features; ACAP.decode of them is the mesh."""
    from experiments.export import main

    main([str(run_dir), "--format", "torchscript", "--out", str(tmp_path), "--max-dense-vertices", "10"])
    assert json.loads((tmp_path / "manifest.json").read_text())["decoder"]["output"] == "features"
    with torch.no_grad():
        feats = torch.jit.load(str(tmp_path / "decoder.pt"))(fresh_codes)
        torch.testing.assert_close(feats, trained.space.decode_features(fresh_codes), rtol=0, atol=1e-5)
        torch.testing.assert_close(trained.space.acap.decode(feats), trained.decode(fresh_codes), rtol=0, atol=1e-5)


def test_pack_run_loads_without_cache_or_data(run_dir, trained, tmp_path, monkeypatch, capsys):
    """A packed run (neuralcol.api.package) loads from its folder alone: the cache moved away, the paths reset, the
    same detector and decoder; its manifest lists each file's checksum, and a changed file is named."""
    import neuralcol
    from experiments.pack import main as pack_main
    from neuralcol.api.package import check_package

    out = tmp_path / "pkg"
    pack_main([str(run_dir), str(out), "--note", "tiny", "--check", "64", "--workers", "0"])
    check = json.loads(capsys.readouterr().out)
    assert check["n"] + check["n_failed"] == 64 and 0 <= check["accuracy"] <= 1
    manifest = check_package(out)
    assert set(manifest["files"]) >= {".hydra/config.yaml", "metrics.json", "detector.pt", "latent_space.pt"}
    assert manifest["figures"]["u_z"]["n"] == trained.metrics["detector"]["test_set"]["n"]
    assert manifest["note"] == "tiny" and manifest["source"]["command"].startswith("python -m experiments.run")
    cfg = OmegaConf.load(out / ".hydra" / "config.yaml")
    assert OmegaConf.to_container(cfg.paths)["cache_dir"] == "${oc.env:NEURALCOL_CACHE,.cache}"
    monkeypatch.setenv("NEURALCOL_CACHE", str(tmp_path / "empty_cache"))  # the run's cache is not read
    z = _codes(trained, 5, 7)
    with neuralcol.load_run(out) as packed:
        torch.testing.assert_close(packed.detect(z).logit, trained.detect(z).logit, rtol=0, atol=0)
        torch.testing.assert_close(packed.decode(z), trained.decode(z), rtol=0, atol=0)
    with pytest.raises(UserInputError, match="exists; give --overwrite"):
        neuralcol.pack_run(run_dir, out)
    neuralcol.pack_run(run_dir, out, overwrite=True)
    with pytest.raises(UserInputError, match="choose a new folder"):
        neuralcol.pack_run(run_dir, run_dir, overwrite=True)  # never deletes a folder that is not a package
    with open(out / "detector.pt", "r+b") as f:  # one byte changed
        f.seek(100)
        b = f.read(1)
        f.seek(100)
        f.write(bytes([b[0] ^ 1]))
    with pytest.raises(UserInputError, match=r"detector.pt: .* checksum other than package.json"):
        neuralcol.load_run(out)
    neuralcol.pack_run(run_dir, out, overwrite=True)
    (out / "latent_space.pt").write_text("version https://git-lfs.github.com/spec/v1\n")
    with pytest.raises(UserInputError, match=r"latent_space.pt: a Git LFS pointer.*git lfs pull"):
        check_package(out)
    with pytest.raises(UserInputError, match="no shipped model named 'nothing'.*scape"):
        neuralcol.pretrained("nothing")


def test_recalibrate_moves_the_threshold_of_a_package(run_dir, trained, tmp_path, monkeypatch, capsys):
    """experiments.recalibrate on a packed run: the rule's threshold (FNR <= target on the realistic calibration
    set) becomes the package's; logits and the cascade's calibration logits move by exactly that shift, the package
    still loads (checksums rewritten), and measuring again finds nothing left to move."""
    import neuralcol
    from neuralcol.api.recalibrate import measure, rule_sets, write_recalibration
    from neuralcol.stages.cascade import load_calibration

    out = tmp_path / "pkg"
    neuralcol.pack_run(run_dir, out)
    cfg = OmegaConf.load(out / ".hydra" / "config.yaml")
    cfg.paths.cache_dir = str(run_dir.parent / "cache")
    monkeypatch.setenv("NEURALCOL_CACHE", cfg.paths.cache_dir)
    realistic = OmegaConf.to_container(trained.cfg.realistic, resolve=True)
    sets = rule_sets(out, cfg, {**realistic, "seed": 5})  # another draw than the run's own calibration set
    cal_v, cal_y = sets.calibration
    assert cal_y.any() and (~cal_y).any()
    z = _codes(trained, 5, 7)
    with neuralcol.load_run(out) as packed:
        before = packed.detect(cal_v).logit.double().numpy()
        result = measure(packed, sets, 0.2)
        old = (packed.metrics["detector"].get("operating_point") or {}).get("threshold", 0.0)
        cascade_before = load_calibration(out / "cascade.npz")[0] if (out / "cascade.npz").is_file() else None
        op = write_recalibration(packed, result, sets, n_fresh=64, n_handler=2)
    shift = result["shift"]
    assert op["threshold"] == pytest.approx(old + shift)
    assert (op["previous"] or {}).get("threshold", 0.0) == old
    assert np.mean(before[cal_y] <= shift) <= 0.2
    with neuralcol.load_run(out) as packed:  # check_package passes: the manifest lists the new files
        after = packed.detect(cal_v).logit.double().numpy()
        np.testing.assert_allclose(after, before - shift, atol=1e-4)
        assert packed.detect(z).logit.shape == (5,)
        again = measure(packed, sets, 0.2)
        assert abs(again["shift"]) < 1e-4 and again["rule"]["calibration"]["fnr"] <= 0.2
        assert packed.metrics["handling"]["inputs"]["n"] <= 2
        if cascade_before is not None:
            np.testing.assert_allclose(load_calibration(out / "cascade.npz")[0], cascade_before - shift, atol=1e-4)
    manifest = json.loads((out / "package.json").read_text())
    assert manifest["figures"]["threshold"] == pytest.approx(old + shift)
    assert manifest["figures"]["u_z"]["seed"] == 20261129
    from experiments.recalibrate import main as recalibrate_main

    for args, says in (([str(tmp_path)], "not a finished run or a package"),
                       ([str(out), "detector.operating_fnr=0.2"], "only realistic.KEY=VALUE")):
        with pytest.raises(SystemExit) as stop:
            recalibrate_main(args + ["--cache", cfg.paths.cache_dir, "--data", str(tmp_path)])
        assert stop.value.code == 2 and says in capsys.readouterr().err


def test_explain_gap_on_a_finished_run(run_dir):
    """research/paper_scale/explain_gap.py: the final detector re-scored on the U(Z) test set at logit 0 (undoing the
    operating point folded into its bias) equals the run's own last-round figure; the D_c rows' splits partition the
    store; the slope and the extrapolated size agree with an exact log-linear curve."""
    import h5py
    import numpy as np

    from research.paper_scale.explain_gap import explain, scored, size_to_reach, slope, table

    out = explain(run_dir, None, paper=(0.9383, 0.0515))  # (proc_hand is not in the paper's Table 3)
    head, _, line = table([out]).splitlines()  # one cell per column (a stray "test" column shifted the rest)
    acquired = out["rows"]["train acquired"]["at logit 0"]["accuracy"]
    assert head.count(" | ") == line.count(" | ") and f"| {acquired:.4f} | " in line
    assert out["rows"]["test"]["at logit 0"]["accuracy"] == pytest.approx(out["curve"]["accuracy"][-1], abs=1e-9)
    with h5py.File(run_dir / "dc.h5", "r") as f:
        n = int(f.attrs.get("committed", len(f["z"])))
    assert out["rows"]["train all"]["n"] + out["rows"]["validation all"]["n"] == n
    at_fnr = out["rows"]["test"]["at the paper's FNR"]  # a threshold chosen on held-out rows: lower misses less
    assert at_fnr["fnr"] <= out["rows"]["test"]["at logit 0"]["fnr"] or at_fnr["threshold"] >= 0
    sizes = np.array([1e3, 2e3, 4e3, 8e3])
    acc = 0.8 + 0.02 * np.log2(sizes / 1e3)
    assert slope(sizes, acc) == pytest.approx(0.02)
    assert size_to_reach(sizes, acc, 0.9) == pytest.approx(2.0 ** 5 * 1e3, rel=1e-6)
    assert size_to_reach(sizes, acc, 0.8) is None and size_to_reach(sizes, 0.9 - acc, 0.95) is None
    # an operating point at -1.5 folded into the bias: deployed logits 1.0, 2.0 are trained logits -0.5, 0.5
    two = scored(np.array([1.0, 2.0]), np.array([False, True]), -1.5)
    assert two["at logit 0"]["accuracy"] == 1.0 and two["at the operating point"]["accuracy"] == 0.5


def test_each_round_keeps_the_detector_it_was_tested_with(run_dir, trained):
    """``round_detectors/round_<k>.pt`` (for the handler's curve afterwards): one per round, and each
    scores on the run's cached U(Z) test set exactly what the round recorded (the last round at logit 0)."""
    import copy
    import json

    import h5py
    import numpy as np

    from neuralcol.nn.detector import load_detector
    from neuralcol.rundir import RunDir
    from research.speed_rerun import find_test_set

    rounds = json.loads(RunDir(run_dir).detector_rounds.read_text())["rounds"]
    assert len(rounds) > 1
    files = sorted(RunDir(run_dir).round_detectors.glob("round_*.pt"))
    assert [f.name for f in files] == [f"round_{r['round']}.pt" for r in rounds]
    test = find_test_set(Path(trained.cfg.paths.cache_dir), trained.metrics["autoencoder"]["cache_key"],
                         int(trained.cfg.detector.test_seed))
    with h5py.File(test, "r") as f:
        z, y = torch.as_tensor(f["z"][:]), f["collides"][:].astype(bool)
    for r in rounds:
        net = copy.deepcopy(trained.detector)
        net.load_state_dict(load_detector(RunDir(run_dir).round_detector(r["round"]))[0].state_dict())
        with torch.no_grad():
            logit = trained.on_codes.__class__(net.eval(), trained.space)(z).logit.numpy()
        assert float(np.mean((logit > 0) == y)) == pytest.approx(r.get("at_logit_0", r)["accuracy"], abs=1e-12)


def test_handling_curve_from_the_saved_rounds(run_dir, trained):
    """research/paper_scale/handling_curve.py: one point per round; the last round's saved detector guides the handler
    exactly as the run's final ``detector.pt`` does (the tiny run has no operating point: the same network)."""
    from neuralcol.handler.resolve import alm_settings
    from neuralcol.samples.oracle import LatentOracle
    from neuralcol.stages.handler import evaluate_handler
    from research.paper_scale.handling_curve import curve, handler_inputs

    assert trained.metrics["detector"].get("operating_point") is None
    out = curve(run_dir, n_inputs=4, workers=0)
    assert [p["round"] for p in out["points"]] == [r["round"] for r in trained.metrics["rounds"]]
    assert out["missing_rounds"] == [] and out["n_inputs"] == 4
    z, pd = handler_inputs(trained, 4)
    m, _ = evaluate_handler(trained.on_codes, LatentOracle(trained.space, trained.label_pool()), z, pd,
                            alm_settings(trained.cfg.handler.alm), int(trained.cfg.handler.batch_size))
    assert out["points"][-1]["success_rate"] == m["success_rate"]
    assert out["points"][-1]["mean_pd_reduction"] == pytest.approx(m["mean_pd_reduction"], nan_ok=True)


def test_round_gap_scores_a_saved_round_and_refuses_a_wrong_test_set(run_dir, trained, capsys, tmp_path):
    """research/paper_scale/round_gap.py on round 1 of the tiny run: the saved detector's test accuracy is the round's
    record (the script checks it and stops on a mismatch, e.g. another latent space's test set)."""
    import json
    import shutil

    from research.paper_scale.round_gap import main as round_gap

    cache = trained.cfg.paths.cache_dir
    assert round_gap([str(run_dir), "1", "--paper-fnr", "0.2", "--cache-dir", cache]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["test"]["accuracy"] == pytest.approx(trained.metrics["rounds"][1]["accuracy"], abs=1e-12)
    assert out["train uniform"]["n"] > 0 and out["held-out uniform"]["n"] > 0
    # a copy of the run whose round 1 record claims another accuracy: the script names the mismatch
    bad = tmp_path / "bad_run"
    shutil.copytree(run_dir, bad, ignore=shutil.ignore_patterns(".run.lock"))
    rounds = json.loads((bad / "detector_rounds.json").read_text())
    rounds["rounds"][1]["accuracy"] += 0.01
    (bad / "detector_rounds.json").write_text(json.dumps(rounds))
    with pytest.raises(SystemExit, match="not this run's test set"):
        round_gap([str(bad), "1", "--cache-dir", cache])


def test_recalibrate_reads_the_run_s_own_cache_unless_told_otherwise(tmp_path, monkeypatch):
    """experiments.recalibrate's folders: the command line, else the environment, else the run's recorded folder where
    it exists (a recalibration that ignored it labeled a run's realistic sets a second time), else the default."""
    from experiments.recalibrate import folder_for

    run_cache, env_cache, flag = tmp_path / "run_cache", tmp_path / "env_cache", tmp_path / "flag"
    run_cache.mkdir()
    monkeypatch.delenv("NEURALCOL_CACHE", raising=False)
    assert folder_for(None, "NEURALCOL_CACHE", str(run_cache), ".cache") == (run_cache, "the run's own setting")
    assert folder_for(None, "NEURALCOL_CACHE", str(tmp_path / "gone"), ".cache") == (Path(".cache"), "default")
    assert folder_for(None, "NEURALCOL_CACHE", None, ".cache") == (Path(".cache"), "default")
    monkeypatch.setenv("NEURALCOL_CACHE", str(env_cache))
    assert folder_for(None, "NEURALCOL_CACHE", str(run_cache), ".cache") == (env_cache, "NEURALCOL_CACHE")
    assert folder_for(flag, "NEURALCOL_CACHE", str(run_cache), ".cache") == (flag, "command line")


def test_recalibration_labels_only_the_fresh_codes_the_handler_needs_when_the_run_has_a_test_set(tmp_path):
    """A package has no test set: its new threshold is scored on --fresh codes, all labeled. A run with its own test
    set scores it there, so the fresh codes only feed the handler: as many as give --handler colliding codes at the
    test set's rate of collisions, half as many again to spare, never more than --fresh (on a 13k-vertex body the
    10 000 default cost ~40 minutes of labels for 500 handler inputs)."""
    from neuralcol.api.recalibrate import fresh_codes_needed
    from neuralcol.rundir import RunDir

    rd = RunDir(tmp_path)
    assert fresh_codes_needed(rd, 10000, 500) == 10000  # a package: every fresh code scores the threshold
    np.savez(rd.test_predictions, logit=np.zeros(400), collides=np.arange(400) % 4 == 0)  # a quarter collide
    assert fresh_codes_needed(rd, 10000, 500) == 3000  # 1.5 x 500 / 0.25
    assert fresh_codes_needed(rd, 2000, 500) == 2000
    assert fresh_codes_needed(rd, 10000, 0) == 0
    np.savez(rd.test_predictions, logit=np.zeros(4), collides=np.zeros(4, bool))  # no collision: the rate's floor
    assert fresh_codes_needed(rd, 100000, 500) == 15000

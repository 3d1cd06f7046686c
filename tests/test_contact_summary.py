"""Per-sub-domain summaries of every close vertex pair (neuralcol.geometry.contact_summary), against a brute force
over all vertex pairs and between their numpy and torch forms."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from neuralcol.geometry.contact_pairs import hop_neighbourhood
from neuralcol.geometry.contact_summary import (
    SUMMARIES,
    ContactSummary,
    farthest_point_sample,
    reusing_neighbours,
    vertex_normals_np,
)


def _bent_sheet(n: int = 12, bend: float = 0.0):
    """A grid sheet folded about its middle row by ``bend`` radians (pi: flat onto itself), and its rest pose."""
    u, v = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 2, 2 * n - 1), indexing="ij")
    rest = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], 1)
    idx = np.arange(u.size).reshape(u.shape)
    faces = np.concatenate([np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:]], -1).reshape(-1, 3),
                            np.stack([idx[:-1, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 3)])
    x = rest.copy()
    above = x[:, 1] > 1
    t = x[above, 1] - 1
    x[above, 1] = 1 + t * np.cos(bend)
    x[above, 2] = t * np.sin(bend)
    partition = (rest[:, 1] > 1).astype(np.int64)  # two sub-domains: below and above the fold
    return rest, x, faces, partition


def _brute(summary: ContactSummary, v: np.ndarray) -> np.ndarray:
    near = hop_neighbourhood(summary.faces, len(v), 2).toarray()
    normals = vertex_normals_np(v, summary.faces)
    k = summary.n_parts
    out = np.zeros((k, len(SUMMARIES)))
    out[:, 1:3] = 1.0
    out[:, 3] = summary.clip
    count = np.zeros(k)
    for i in range(len(v)):
        for j in range(i + 1, len(v)):
            d = np.linalg.norm(v[j] - v[i])
            dr = np.linalg.norm(summary.rest[j] - summary.rest[i])
            if d >= summary.radius or near[i, j] or d >= summary.fold_ratio * dr:
                continue
            off = min((v[j] - v[i]) @ normals[i], (v[i] - v[j]) @ normals[j]) / summary.radius
            off = np.clip(off, -summary.clip, summary.clip)
            for p in (summary.partition[i], summary.partition[j]):
                count[p] += 1
                out[p, 1] = min(out[p, 1], d / dr)
                out[p, 2] = min(out[p, 2], d / summary.radius)
                out[p, 3] = min(out[p, 3], off)
    out[:, 0] = np.log1p(count)
    return out


@pytest.mark.parametrize("bend", [0.0, 2.6, 3.0, 3.3])
def test_summaries_equal_a_brute_force_over_all_pairs(bend):
    rest, x, faces, partition = _bent_sheet(bend=bend)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    got = s.summarize(x[None])[0]
    np.testing.assert_allclose(got, _brute(s, x), rtol=1e-6, atol=1e-6)
    if bend == 0.0:  # a flat sheet has no close pair
        np.testing.assert_array_equal(got, [[0, 1, 1, 3], [0, 1, 1, 3]])


def test_a_fold_through_itself_turns_the_offset_negative():
    rest, _, faces, partition = _bent_sheet()
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    touching = s.summarize(_bent_sheet(bend=3.0)[1][None])[0]
    through = s.summarize(_bent_sheet(bend=3.3)[1][None])[0]
    assert touching[0, 3] > 0 and through[0, 3] < 0
    assert touching[0, 0] > 0 and through[0, 0] > 0


def test_torch_form_equals_numpy_and_passes_gradients_to_the_closest_pair():
    rest, x, faces, partition = _bent_sheet(bend=3.0)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    xs = np.stack([x, _bent_sheet(bend=2.8)[1], rest])
    t = torch.tensor(xs, dtype=torch.float64, requires_grad=True)
    got = s.summarize_torch(t)
    np.testing.assert_allclose(got.detach().numpy(), s.summarize(xs), rtol=1e-6, atol=1e-6)
    got[0, 0, 2].backward()  # the smallest distance over the radius of mesh 0, sub-domain 0
    pr = s.close_pairs(x)
    d = np.linalg.norm(x[pr[:, 1]] - x[pr[:, 0]], axis=1)
    closest = np.unique(pr[np.isclose(d, d.min(), rtol=1e-12)])  # (a symmetric fold ties several pairs)
    moved = np.flatnonzero(t.grad[0].norm(dim=1).numpy() > 0)
    assert len(moved) > 0 and set(moved) <= set(closest)
    assert torch.all(t.grad[1:] == 0)


def test_a_body_mesh_finds_the_same_pairs_as_scipy_sparse_filtering():
    body = trimesh.creation.capsule(height=1.0, radius=0.3, count=[16, 16])
    rest = np.asarray(body.vertices)
    faces = np.asarray(body.faces)
    squashed = rest * np.array([1.0, 1.0, 0.05])  # flattened: the two sides come together
    s = ContactSummary(rest, faces, np.zeros(len(rest), np.int64), 1, radius=0.2)
    pr = s.close_pairs(squashed)
    near = hop_neighbourhood(faces, len(rest), 2)
    assert len(pr) > 0 and not np.asarray(near[pr[:, 0], pr[:, 1]]).any()
    d = np.linalg.norm(squashed[pr[:, 1]] - squashed[pr[:, 0]], axis=1)
    assert np.all(d < 0.2)


def test_bad_inputs_say_what_is_wrong():
    rest, x, faces, partition = _bent_sheet()
    with pytest.raises(ValueError, match="partition"):
        ContactSummary(rest, faces, partition[:-1], 2, radius=0.3)
    with pytest.raises(ValueError, match="radius"):
        ContactSummary(rest, faces, partition, 2, radius=0.0)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    with pytest.raises(ValueError, match="expected"):
        s.summarize(x)


def test_grid_search_finds_the_pairs_a_kdtree_finds_on_a_crumpled_body():
    """The compiled grid search against scipy's k-d tree with the same rules, on a capsule squashed and twisted
    (thousands of pairs within the radius, hundreds close)."""
    from scipy.spatial import cKDTree

    body = trimesh.creation.capsule(height=1.0, radius=0.3, count=[24, 24])
    rest = np.asarray(body.vertices)
    faces = np.asarray(body.faces)
    rng = np.random.default_rng(3)
    x = rest * np.array([1.0, 1.0, 0.08]) + 0.01 * rng.normal(size=rest.shape)
    angle = 2.0 * x[:, 0]
    x = np.stack([x[:, 0], np.cos(angle) * x[:, 1] - np.sin(angle) * x[:, 2],
                  np.sin(angle) * x[:, 1] + np.cos(angle) * x[:, 2]], 1)
    s = ContactSummary(rest, faces, np.zeros(len(rest), np.int64), 1, radius=0.06)
    got = {tuple(p) for p in s.close_pairs(x)}
    pr = np.sort(cKDTree(x).query_pairs(0.06, output_type="ndarray"), axis=1)
    near = hop_neighbourhood(faces, len(rest), 2)
    pr = pr[np.asarray(near[pr[:, 0], pr[:, 1]]).ravel() == 0]
    d = np.linalg.norm(x[pr[:, 1]] - x[pr[:, 0]], axis=1)
    dr = np.linalg.norm(rest[pr[:, 1]] - rest[pr[:, 0]], axis=1)
    want = {tuple(p) for p in pr[d < 0.5 * dr]}
    assert len(want) > 100 and got == want
    with pytest.raises(ValueError, match="NaN"):
        s.close_pairs(np.full_like(x, np.nan))


@pytest.mark.parametrize("smooth", [False, True])
def test_gradients_match_finite_differences_for_every_summary(smooth):
    """The minima's gradients (distance, ratio and the signed offset through the vertex normals) and, in the smooth
    form, the weighted count's against central differences, on a fold with noise (no ties, the same close pairs
    within the step)."""
    rest, x, faces, partition = _bent_sheet(n=8, bend=3.1)
    x = x + 0.004 * np.random.default_rng(0).normal(size=x.shape)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3, smooth=smooth)
    t = torch.tensor(x[None], dtype=torch.float64, requires_grad=True)
    assert s.close_pairs(x).shape[0] > 10
    for col in (0, 1, 2, 3) if smooth else (1, 2, 3):
        assert torch.autograd.gradcheck(lambda v, col=col: s.summarize_torch(v)[..., col], (t,), eps=1e-7,
                                        atol=1e-5)


@pytest.mark.parametrize("smooth", [False, True])
def test_reused_neighbour_lists_give_what_a_fresh_search_gives(smooth):
    """Inside reusing_neighbours() meshes that barely moved take their stored candidates, meshes that moved far are
    searched anew; every summary equals the numpy form's fresh search."""
    rest, x, faces, partition = _bent_sheet(bend=3.0)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3, smooth=smooth)
    rng = np.random.default_rng(1)
    steps = [x + 0.02 * rng.normal(size=x.shape) for _ in range(2)]  # small moves: reused
    steps.append(_bent_sheet(bend=3.3)[1])  # a large one: searched
    steps.append(steps[-1] + 0.01 * rng.normal(size=x.shape))
    with reusing_neighbours():
        for v in [x] + steps:
            batch = np.stack([v, rest])  # the rest mesh beside it: the same row keeps its own list
            got = s.summarize_torch(torch.tensor(batch, requires_grad=True)).detach().numpy()
            want = s.summarize(batch)  # (float32)
            np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6)
            if not smooth:
                np.testing.assert_array_equal(np.round(np.expm1(got[..., 0])), np.round(np.expm1(want[..., 0])))
    lists = s.neighbour_lists
    assert lists.reuses >= 4 and lists.searches >= 3


def test_a_vertex_thrown_far_away_costs_no_memory():
    """The grid is hashed: a mesh spread over 1e9 radii still finds its pairs (a dense grid would need 1e27 cells)."""
    rest, x, faces, partition = _bent_sheet(bend=3.0)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    far = x.copy()
    far[0] = [3e8, -3e8, 3e8]
    want = {tuple(p) for p in s.close_pairs(x) if 0 not in p}
    assert want and {tuple(p) for p in s.close_pairs(far)} == want


def test_a_vertex_sample_keeps_the_pairs_among_its_vertices():
    """With max_vertices the pairs are the full search's pairs whose two vertices are in the sample, spread evenly
    (farthest-point sampling: no point of the rest mesh far from the sample)."""
    body = trimesh.creation.capsule(height=1.0, radius=0.3, count=[24, 24])
    rest, faces = np.asarray(body.vertices), np.asarray(body.faces)
    x = rest * np.array([1.0, 1.0, 0.08])
    full = ContactSummary(rest, faces, np.zeros(len(rest), np.int64), 1, radius=0.06)
    part = ContactSummary(rest, faces, np.zeros(len(rest), np.int64), 1, radius=0.06, max_vertices=200)
    assert len(part.sample) == 200 and np.all(np.diff(part.sample) > 0)
    keep = np.isin(full.close_pairs(x), part.sample).all(1)
    want = {tuple(p) for p in full.close_pairs(x)[keep]}
    assert len(want) > 20 and {tuple(p) for p in part.close_pairs(x)} == want
    np.testing.assert_allclose(part.summarize_torch(torch.tensor(x[None])).numpy(), part.summarize(x[None]),
                               rtol=1e-6)
    gap = np.linalg.norm(rest[:, None] - rest[part.sample][None], axis=2).min(1)
    spacing = np.linalg.norm(rest[faces[:, 0]] - rest[faces[:, 1]], axis=1).mean()
    assert gap.max() < 3 * spacing * np.sqrt(len(rest) / 200)
    assert np.array_equal(farthest_point_sample(rest, 10**6), np.arange(len(rest)))


def test_the_smooth_form_is_continuous_where_a_pair_stops_being_close():
    """Opening a fold past the radius: the plain summaries jump when the last pair leaves, the smooth ones reach their
    no-pair values (0, 1, 1, clip) continuously; both forms agree with the numpy reference."""
    rest, _, faces, partition = _bent_sheet(n=8, bend=3.0)
    plain = ContactSummary(rest, faces, partition, 2, radius=0.3)
    smooth = ContactSummary(rest, faces, partition, 2, radius=0.3, smooth=True)
    bends = np.linspace(1.6, 3.0, 281)
    meshes = np.stack([_bent_sheet(n=8, bend=b)[1] for b in bends])
    for form in (plain, smooth):
        t = form.summarize_torch(torch.tensor(meshes)).numpy()
        np.testing.assert_allclose(t, form.summarize(meshes), rtol=1e-5, atol=1e-6)
    jumps = {name: np.abs(np.diff(form.summarize(meshes), axis=0)).max() for name, form in
             (("plain", plain), ("smooth", smooth))}
    assert jumps["plain"] > 0.3 and jumps["smooth"] < 0.1
    assert np.allclose(smooth.summarize(meshes[:1])[0], [0, 1, 1, 3.0], atol=1e-6)  # open: no close pair


def test_the_parallel_kernels_leave_torch_on_its_pinned_thread_count():
    """numba's OpenMP layer sets the process's thread count; torch's (pinned for repeatable numbers) comes back."""
    rest, x, faces, partition = _bent_sheet(bend=3.0)
    s = ContactSummary(rest, faces, partition, 2, radius=0.3)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        s.summarize_torch(torch.tensor(np.stack([x, rest])))
        with reusing_neighbours():
            s.summarize_torch(torch.tensor(np.stack([x, rest]), requires_grad=True))
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)

"""Per-sub-domain contact pairs (neuralcol/nn/part_geometry.py) on hand-made meshes with known answers."""

import numpy as np
import torch

from neuralcol.geometry.contact_pairs import ContactFeatures
from neuralcol.nn.part_geometry import PartGeometry, choose_part_pairs, close_pair_scores

# two unit triangles stacked along z: A = vertices 0-2 at z = 0, B = vertices 3-5 at z = h
TRI = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
FACES = np.array([[0, 1, 2], [3, 5, 4]])


def stacked(h: float) -> np.ndarray:
    return np.concatenate([TRI, TRI + [0.0, 0.0, h]])


def test_close_pairs_count_approaches_weighted_by_label():
    rest = stacked(10.0)
    meshes = np.stack([stacked(0.05), stacked(0.2), stacked(5.0)])
    pairs, scores = close_pair_scores(meshes, np.array([True, False, False]), rest, FACES, radius=0.5, min_hops=1,
                                      fold_ratio=0.5, colliding_weight=3.0)
    # only the three vertical pairs come within 0.5; closer than half their rest distance in meshes 0 and 1
    assert pairs.tolist() == [[0, 3], [1, 4], [2, 5]]
    np.testing.assert_array_equal(scores, [4.0, 4.0, 4.0])


def test_pairs_close_at_rest_or_within_hops_never_count():
    # B rests 0.3 above A: at 0.2 the pairs are not closer than half their rest distance (a surface's own closeness)
    pairs, _ = close_pair_scores(stacked(0.2)[None], np.array([True]), stacked(0.3), FACES, radius=0.5,
                                 min_hops=1, fold_ratio=0.5, colliding_weight=3.0)
    assert len(pairs) == 0
    # a squashed triangle brings its own vertices close: within one edge, so never a pair
    squashed = stacked(10.0)
    squashed[1] = [0.1, 0.0, 0.0]
    pairs, _ = close_pair_scores(squashed[None], np.array([True]), stacked(10.0), FACES, radius=0.5, min_hops=1,
                                 fold_ratio=0.5, colliding_weight=3.0)
    assert len(pairs) == 0


def test_choose_part_pairs_gives_each_subdomain_its_best_slots():
    pairs = np.array([[0, 3], [1, 4], [2, 5], [0, 1]])
    scores = np.array([1.0, 5.0, 3.0, 9.0])
    partition = np.array([0, 0, 0, 1, 1, 1, 2])  # sub-domain 2 (vertex 6) takes part in no pair
    chosen, slots, mask = choose_part_pairs(pairs, scores, partition, 3, per_part=2)
    # part 0: (0,1) 9 and (1,4) 5; part 1: (1,4) 5 and (2,5) 3; chosen pairs best first
    assert chosen.tolist() == [[0, 1], [1, 4], [2, 5]]
    assert [chosen[s].tolist() for s in slots[0]] == [[0, 1], [1, 4]]
    assert [chosen[s].tolist() for s in slots[1]] == [[1, 4], [2, 5]]
    assert mask.tolist() == [[True, True], [True, True], [False, False]]


def test_part_geometry_lays_out_the_contact_features_per_subdomain():
    chosen, slots, mask = choose_part_pairs(np.array([[0, 3], [1, 4]]), np.array([2.0, 1.0]),
                                            np.array([0, 0, 0, 1, 1, 1]), 2, per_part=3)
    geo = PartGeometry(chosen, slots, mask, FACES, radius=0.5)
    v = torch.as_tensor(np.stack([stacked(0.05), stacked(-0.1)]), dtype=torch.float32)
    f = geo.pair_features(v)  # (B, P, 3)
    ref = ContactFeatures(chosen, FACES, 0.5)(v)  # (B, 3 P) as [dist..., s_min..., s_max...]
    torch.testing.assert_close(f, ref.reshape(2, 3, -1).transpose(1, 2))
    # A's normal is +z, B's -z (reversed winding): the two face each other while B is above A, and the signed
    # offsets turn negative once B has passed through A
    assert torch.all(f[0, :, 1] * f[1, :, 1] < 0)
    g = geo.per_part(f)
    assert g.shape == (2, 2, 3, 3)
    torch.testing.assert_close(g[:, 0, :2], f[:, [0, 1]])
    assert torch.all(g[:, :, 2] == 0) and mask[:, 2].tolist() == [False, False]
    assert set(geo.vertex_index.tolist()) == set(range(6))


def test_scores_do_not_depend_on_when_they_are_folded():
    rest = stacked(10.0)
    meshes = np.stack([stacked(h) for h in (0.05, 0.1, 0.2, 0.3, 5.0)])
    labels = np.array([True, True, False, False, False])
    args = (meshes, labels, rest, FACES, 0.5, 1, 0.5, 3.0)
    once = close_pair_scores(*args)
    often = close_pair_scores(*args, fold_at=1)
    np.testing.assert_array_equal(once[0], often[0])
    np.testing.assert_array_equal(once[1], often[1])
    np.testing.assert_array_equal(once[1], [8.0, 8.0, 8.0])

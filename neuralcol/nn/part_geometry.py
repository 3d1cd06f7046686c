"""Penetration-aware geometry of each sub-domain: what the detector over code and mesh reads besides the code.

A self-collision is two pieces of surface coming close and passing through each other: far apart on the mesh
(an arm through the torso) or near on it but folded onto each other (a bent finger joint). :func:`choose_part_pairs`
picks vertex pairs that come close in example meshes while they are apart on the rest mesh:

* a pair is *close* in a mesh when its distance is below ``radius`` and below ``fold_ratio`` times its rest
  distance (so a pair that is close on the rest mesh already, a surface's own closeness, never counts, while
  a local fold, whose vertices a few edges apart approach each other, does);
* pairs within ``min_hops`` edges of each other are never chosen (their closeness is the triangle fan's own);
* a close pair in a colliding example counts ``colliding_weight``; the most frequent pairs win, up to
  ``per_part`` pairs for each sub-domain (a pair belongs to the sub-domains of both of its vertices), so every
  sub-domain gets its own slots and ``S_i`` keeps reading its own surface.

:class:`PartGeometry` measures, for every chosen pair of a mesh, the three numbers of
:class:`~neuralcol.geometry.contact_pairs.ContactFeatures` (distance and the two signed normal offsets, in units of
``radius``, clipped) and lays them out per sub-domain as ``(B, K, M, 3)`` with a mask of the filled slots. It needs
only the pair vertices and the faces around them, so it is computed from the few decoded vertices a code needs
(``space.decode_vertices``) or from a user's whole mesh alike, and it is differentiable in the vertices.

Symbols: B batch, V vertices, K sub-domains, P chosen pairs, M slots per sub-domain.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import nn

from neuralcol.geometry.contact_pairs import (
    ContactFeatures,
    contact_features,
    contact_features_batch_last,
    fold_pair_scores,
    hop_neighbourhood,
)
from neuralcol.geometry.contact_summary import ContactSummary
from neuralcol.nn.inference import batched_logits
from neuralcol.utils.files import atomic_path
from neuralcol.utils.progress import progress_bar

INPUTS = ("latent", "code_and_mesh")  # detector.inputs
SUMMARY_ROWS = 256  # the largest batch timed for a detector that reads contact summaries (a CPU search per mesh)


def close_pair_scores(meshes: np.ndarray, collides: np.ndarray, rest: np.ndarray, faces: np.ndarray,
                      radius: float, min_hops: int, fold_ratio: float, colliding_weight: float,
                      fold_at: int = 20_000_000) -> tuple[np.ndarray, np.ndarray]:
    """How often each vertex pair comes close in ``meshes`` (see the module doc for *close*). The scores are
    folded into running sums whenever ``fold_at`` pairs are buffered
    (:func:`~neuralcol.geometry.contact_pairs.fold_pair_scores`; a body has ~10^6 close pairs per mesh).

    Returns:
        (pairs (Q, 2) int64 with i < j, scores (Q,)): every pair close in at least one mesh, by key order.
    """
    meshes = np.asarray(meshes, np.float64)
    rest = np.asarray(rest, np.float64)
    n_vert = len(rest)
    if meshes.ndim != 3 or meshes.shape[1:] != rest.shape:
        raise ValueError(f"meshes have shape {meshes.shape}, expected (N, {n_vert}, 3)")
    near = hop_neighbourhood(faces, n_vert, min_hops)
    uniq, score = np.zeros(0, np.int64), np.zeros(0)
    keys, weights, n_buffered = [], [], 0
    for v, c in zip(meshes, np.asarray(collides, bool)):
        pr = cKDTree(v).query_pairs(float(radius), output_type="ndarray")
        if len(pr) == 0:
            continue
        pr = np.sort(pr, axis=1)
        pr = pr[np.asarray(near[pr[:, 0], pr[:, 1]]).ravel() == 0]
        d = np.linalg.norm(v[pr[:, 1]] - v[pr[:, 0]], axis=1)
        d_rest = np.linalg.norm(rest[pr[:, 1]] - rest[pr[:, 0]], axis=1)
        pr = pr[d < fold_ratio * d_rest]
        keys.append(pr[:, 0] * n_vert + pr[:, 1])
        weights.append(np.full(len(pr), float(colliding_weight) if c else 1.0))
        n_buffered += len(pr)
        if n_buffered >= fold_at:
            uniq, score = fold_pair_scores(uniq, score, keys, weights)
            keys, weights, n_buffered = [], [], 0
    uniq, score = fold_pair_scores(uniq, score, keys, weights)
    return np.stack([uniq // n_vert, uniq % n_vert], 1).astype(np.int64), score


def choose_part_pairs(pairs: np.ndarray, scores: np.ndarray, partition: np.ndarray, n_parts: int,
                      per_part: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Up to ``per_part`` best-scored pairs for each sub-domain.

    Args:
        pairs, scores: candidate pairs and their scores (:func:`close_pair_scores`).
        partition: (V,) sub-domain of each vertex. n_parts: K. per_part: M.

    Returns:
        (chosen pairs (P, 2), slots (K, M) int64 indices into the chosen pairs (0 where empty),
        mask (K, M) bool: filled slots).
    """
    partition = np.asarray(partition, np.int64)
    order = np.lexsort((np.arange(len(scores)), -np.asarray(scores)))  # best first, ties by index
    per = [[] for _ in range(n_parts)]
    for q in order:
        i, j = pairs[q]
        for k in {int(partition[i]), int(partition[j])}:
            if len(per[k]) < per_part:
                per[k].append(int(q))
        if all(len(p) >= per_part for p in per):
            break
    used = sorted({q for p in per for q in p}, key=lambda q: (-scores[q], q))
    index = {q: n for n, q in enumerate(used)}
    slots = np.zeros((n_parts, per_part), np.int64)
    mask = np.zeros((n_parts, per_part), bool)
    for k, p in enumerate(per):
        slots[k, :len(p)] = [index[q] for q in p]
        mask[k, :len(p)] = True
    chosen = pairs[np.asarray(used, np.int64)] if used else np.zeros((0, 2), np.int64)
    return chosen.reshape(-1, 2), slots, mask


def choose_geometry(space, meshes: np.ndarray, collides: np.ndarray | None = None, radius: float = 0.02,
                    min_hops: int = 2, fold_ratio: float = 0.5, colliding_weight: float = 3.0, per_part: int = 32,
                    clip: float = 3.0, summaries: bool = False, summary_vertices: int | None = None,
                    summary_smooth: bool = False) -> PartGeometry:
    """The :class:`PartGeometry` of a latent space, its pairs chosen on example meshes.

    Args:
        space: the latent space (its rest mesh, faces and sub-domains ``partition``).
        meshes: (N, V, 3) examples (decoded codes, realistic training meshes).
        collides: (N,) their exact labels, or None (unlabeled examples each count once).
        radius: closeness radius and feature unit, a fraction of the rest mesh's bounding-box diagonal.
        min_hops, fold_ratio, colliding_weight: see :func:`close_pair_scores`. per_part: M slots per sub-domain.
        clip: features clipped to ``[-clip, clip]`` radii.
        summaries: also read the summaries of every close pair per sub-domain (:class:`PartGeometry`), with the
            same radius, min_hops and fold_ratio. summary_vertices: their pairs among at most this many vertices
            (``ContactSummary``'s ``max_vertices``; None: all). summary_smooth: their continuous form
            (``ContactSummary``'s ``smooth``).

    Raises:
        ValueError: no pair comes close in the examples (the message says what to raise).
    """
    rest = space.rest_vertices.detach().cpu().numpy().astype(np.float64)
    faces = space.faces.detach().cpu().numpy()
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    labels = np.zeros(len(meshes), bool) if collides is None else np.asarray(collides, bool)
    weight = float(colliding_weight) if collides is not None else 1.0
    pairs, scores = close_pair_scores(meshes, labels, rest, faces, radius * diag, min_hops, fold_ratio, weight)
    if len(pairs) == 0:
        raise ValueError(f"no vertex pair at least {min_hops} edges apart comes within radius={radius} of the "
                         f"diagonal and {fold_ratio} of its rest distance in the {len(meshes)} examples; raise the "
                         "radius or give more examples")
    partition = space.partition.detach().cpu().numpy()
    chosen, slots, mask = choose_part_pairs(pairs, scores, partition, int(partition.max()) + 1, per_part)
    return PartGeometry(chosen, slots, mask, faces, radius * diag, clip,
                        space_summaries(space, min_hops, fold_ratio, summary_vertices, summary_smooth) if summaries
                        else None)


def space_summaries(space, min_hops: int, fold_ratio: float, max_vertices: int | None = None,
                    smooth: bool = False) -> dict:
    """:class:`PartGeometry`'s ``summaries`` argument for a latent space's topology."""
    return {"rest": space.rest_vertices.detach().cpu().numpy().astype(np.float64),
            "faces": space.faces.detach().cpu().numpy(), "partition": space.partition.detach().cpu().numpy(),
            "min_hops": int(min_hops), "fold_ratio": float(fold_ratio),
            "max_vertices": None if max_vertices is None else int(max_vertices), "smooth": bool(smooth)}


class PartGeometry(nn.Module):
    """(B, V', 3) vertices -> (B, P, 3) pair features, and their per-sub-domain layout (B, K, M, 3).

    With ``summaries``, each sub-domain also reads the summaries of every close pair of the mesh touching it
    (:class:`~neuralcol.geometry.contact_summary.ContactSummary`: count, closest ratio and distance, signed offset,
    found anew per mesh), laid out as two more rows of three per sub-domain after the P chosen pairs
    (``[log_count, min_ratio, min_dist]``, ``[min_offset, 0, 0]``) and two more slots per sub-domain: the features are
    then ``(B, P + 2 K, 3)``, ``n_pairs`` counts those rows and ``vertex_index`` is every vertex (the summaries need the
    whole mesh).

    Args:
        pairs: (P, 2) chosen pairs. slots, mask: (K, M) (:func:`choose_part_pairs`).
        faces: (F, 3) triangles. radius: the feature unit. clip: features clipped to ``[-clip, clip]``.
        summaries: None, or ``{"rest": (V, 3), "faces": (F, 3) every triangle, "partition": (V,), "min_hops",
            "fold_ratio", "max_vertices" (optional, None: all), "smooth" (optional, False)}`` (the closeness rule of
            the summaries, radius and clip as the pairs').
    """

    def __init__(self, pairs: np.ndarray, slots: np.ndarray, mask: np.ndarray, faces: np.ndarray, radius: float,
                 clip: float = 3.0, summaries: dict | None = None):
        super().__init__()
        self.contact = ContactFeatures(pairs, faces, radius, clip)
        slots, mask = np.asarray(slots, np.int64), np.asarray(mask, bool)
        k = slots.shape[0]
        self.n_fixed_slots = int(slots.shape[1])
        self.summary = None
        if summaries is not None:
            rest = np.asarray(summaries["rest"], np.float64)
            all_faces = np.asarray(summaries["faces"], np.int64)
            partition = np.asarray(summaries["partition"], np.int64)
            self.summary = ContactSummary(rest, all_faces, partition, k, float(self.contact.radius),
                                          int(summaries["min_hops"]), float(summaries["fold_ratio"]), float(clip),
                                          summaries.get("max_vertices"), bool(summaries.get("smooth", False)))
            self.register_buffer("summary_rest", torch.as_tensor(rest))
            self.register_buffer("summary_faces", torch.as_tensor(all_faces))
            self.register_buffer("summary_partition", torch.as_tensor(partition))
            extra = self.contact.n_pairs + 2 * np.arange(k)[:, None] + np.arange(2)[None, :]  # (K, 2) summary rows
            slots = np.concatenate([slots, extra], 1)
            mask = np.concatenate([mask, np.ones((k, 2), bool)], 1)
            used = torch.arange(len(rest))
        else:
            used = torch.unique(torch.cat([self.contact.pairs.reshape(-1), self.contact.faces.reshape(-1)]))
        self.register_buffer("vertex_index", used)  # the vertices the features read (pairs and their faces)
        # the same pairs and faces numbered within vertex_index: the features of the V' vertices alone (not saved)
        local = torch.full((int(used.max()) + 1 if len(used) else 1,), -1, dtype=torch.long)
        local[used] = torch.arange(len(used))
        self.register_buffer("local_pairs", local[self.contact.pairs], persistent=False)
        self.register_buffer("local_faces", local[self.contact.faces], persistent=False)
        self.register_buffer("slots", torch.as_tensor(slots, dtype=torch.long))
        self.register_buffer("mask", torch.as_tensor(mask, dtype=torch.bool))
        # the per-sub-domain layout as rows of the batch-last features (3 P, B) plus one zero row (index 3 P) for
        # the empty slots: slot (k, m), feature c -> row c P + slots[k, m] (not saved: derived)
        p = self.n_pairs
        rows = torch.arange(3)[None, None, :] * p + self.slots[:, :, None]
        self.register_buffer("slot_rows", torch.where(self.mask[:, :, None], rows, 3 * p).reshape(-1),
                             persistent=False)

    @property
    def fixed_slots(self) -> tuple[np.ndarray, np.ndarray]:
        """The chosen pairs' own slots and mask (K, M), without the summaries' two slots per sub-domain."""
        m = self.n_fixed_slots
        return self.slots[:, :m].cpu().numpy(), self.mask[:, :m].cpu().numpy()

    def summary_settings(self) -> dict | None:
        """What rebuilds the summaries (the ``summaries`` argument), or None without them."""
        if self.summary is None:
            return None
        return {"rest": self.summary_rest.cpu().numpy(), "faces": self.summary_faces.cpu().numpy(),
                "partition": self.summary_partition.cpu().numpy(), "min_hops": self.summary.min_hops,
                "fold_ratio": self.summary.fold_ratio, "max_vertices": self.summary.max_vertices,
                "smooth": self.summary.smooth}

    def _summary_rows(self, vertices: torch.Tensor) -> torch.Tensor:
        """Whole meshes (B, V, 3) -> their summaries as feature rows (B, 2 K, 3) (see the class doc)."""
        s = self.summary.summarize_torch(vertices)  # (B, K, 4)
        s = torch.cat([s, s.new_zeros(*s.shape[:2], 2)], -1)  # (B, K, 6)
        return s.reshape(len(s), -1, 3)

    @property
    def n_pairs(self) -> int:
        """Feature rows: the chosen pairs, and two per sub-domain with summaries."""
        return self.contact.n_pairs + (0 if self.summary is None else 2 * int(self.slots.shape[0]))

    def pair_features(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V, 3) whole meshes -> (B, P, 3) [dist, s_min, s_max] per pair."""
        return self.features_of_vertices(vertices[:, self.vertex_index])

    def features_of_vertices(self, vertices: torch.Tensor) -> torch.Tensor:
        """(B, V', 3) the vertices ``vertex_index`` only -> (B, P, 3): what :meth:`pair_features` gives for the
        whole meshes (the normals at the pair vertices need only the faces around them)."""
        f = contact_features(vertices, self.local_pairs, self.local_faces, self.contact.radius, self.contact.clip)
        f = f.reshape(len(f), 3, -1).transpose(1, 2)  # (B, 3 P) as [dist..., s_min..., s_max...] -> (B, P, 3)
        if self.summary is None:
            return f
        return torch.cat([f, self._summary_rows(vertices).to(f.dtype)], 1)

    def features_batch_last(self, x: torch.Tensor) -> torch.Tensor:
        """The vertices ``vertex_index`` batch last, (V', 3, B) -> (3 P, B) ``[dist..., s_min..., s_max...]``:
        :meth:`features_of_vertices` without its two transposes (the fast path on codes, :class:`DetectorOnCodes`)."""
        f = contact_features_batch_last(x, self.local_pairs, self.local_faces, self.contact.radius,
                                        self.contact.clip)
        if self.summary is None:
            return f
        b = x.shape[2]
        rows = self._summary_rows(x.permute(2, 0, 1)).to(f.dtype).permute(2, 1, 0)  # (3, 2 K, B)
        return torch.cat([f.view(3, -1, b), rows], 1).reshape(-1, b)

    def per_part_batch_last(self, feats: torch.Tensor) -> torch.Tensor:
        """(3 P, B) batch-last features -> (K, 3 M, B): each sub-domain's slots as ``per_part(...).flatten(2)``
        lays them out (slot-major, the 3 features minor), empty slots zero."""
        k, m = self.slots.shape
        padded = torch.cat([feats, feats.new_zeros(1, feats.shape[1])])
        return padded[self.slot_rows].view(k, 3 * m, feats.shape[1])

    def per_part(self, pair_feats: torch.Tensor) -> torch.Tensor:
        """(B, P, 3) -> (B, K, M, 3), empty slots zero (use ``mask``)."""
        out = pair_feats[:, self.slots]  # (B, K, M, 3)
        return out * self.mask[None, :, :, None]


def reads_summaries(net) -> bool:
    """Whether a detector (or a :class:`DetectorOnCodes` around one) reads contact summaries: such a detector
    searches every mesh's close pairs on the CPU, so it is not compiled and is timed on at most
    :data:`SUMMARY_ROWS` rows."""
    geometry = getattr(getattr(net, "detector", net), "geometry", None)
    return geometry is not None and getattr(geometry, "summary", None) is not None


def geometry_of_codes(geometry: PartGeometry, space, z_all: torch.Tensor) -> torch.Tensor:
    """Codes (B, D) -> the pair features (B, P, 3) of the meshes they decode to, decoding only the vertices the
    features read (``space.decode_vertices``); differentiable in ``z_all``."""
    return geometry.features_of_vertices(space.decode_vertices(z_all, geometry.vertex_index.cpu().numpy()))


def vertex_decoder(space, idx: torch.Tensor):
    """A function ``z (B, D) -> (V', 3, B)``: the vertices ``idx`` of ``space.decode(z)`` with the batch last,
    differentiable. The space's own ``vertex_decoder(idx)`` where it has one (a PCA space of vertex positions: one
    product that writes the batch-last layout, no index conversion per call, so ``torch.compile`` fuses it with
    the features); else ``decode_vertices`` and a transpose."""
    own = getattr(space, "vertex_decoder", None)
    if own is not None:
        return own(idx)
    idx_np = idx.cpu().numpy()
    return lambda z: space.decode_vertices(z, idx_np).permute(1, 2, 0)


class DetectorOnCodes(nn.Module):
    """A detector as a function of codes alone: ``z -> detector(z, geometry of decode(z))``.

    Everything that asks the detector about codes (the acquisition, the Newton projector, the handler's constraint,
    the cascade) takes this instead of the detector itself and stays unchanged: for a detector that reads the
    codes only it is the detector; for one that reads the mesh too it decodes, differentiably, the vertices the
    geometry needs, computes their pair features and the detector's embedding of them with the batch last
    (:func:`vertex_decoder`, :meth:`PartGeometry.features_batch_last`,
    :meth:`~neuralcol.nn.detector.CollisionDetector.embed_batch_last`; the same function as
    ``detector(z, geometry_of_codes(...))`` to round-off, 3-4x faster). Without gradients on the CPU a batch runs in
    blocks of ``inference_block`` rows (its intermediates then stay in cache). The latent space is held outside
    the module's parameters and state (it is not trained here).

    Args:
        detector: a :class:`~neuralcol.nn.detector.CollisionDetector`.
        space: the latent space its codes belong to.
    """

    inference_block: int = 128  # rows per block without gradients on the CPU (64-256 alike, 512+ slower)

    def __init__(self, detector: nn.Module, space):
        super().__init__()
        self.detector = detector
        self._space = (space,)  # a tuple: not registered as a submodule
        geometry = getattr(detector, "geometry", None)
        self._decode = None if geometry is None else (vertex_decoder(space, geometry.vertex_index),)

    @property
    def space(self):
        return self._space[0]

    def __deepcopy__(self, memo):
        """A copy of the detector over the same latent space (the space is read, never changed, and holds
        factorizations that cannot be copied)."""
        import copy

        return DetectorOnCodes(copy.deepcopy(self.detector, memo), self.space)

    def embedding(self, z_all: torch.Tensor) -> torch.Tensor:
        """Codes (B, D) -> the detector's geometry embedding (B, K, G) of the meshes they decode to."""
        return self.detector.embed_vertices_batch_last(self._decode[0](z_all))

    def forward(self, z_all: torch.Tensor):
        if self._decode is None:  # (any module of codes alone passes through)
            return self.detector(z_all)
        block = self.inference_block
        if block and len(z_all) > block and z_all.device.type == "cpu" and not torch.is_grad_enabled():
            outs = [self._one(z_all[i:i + block]) for i in range(0, len(z_all), block)]
            return type(outs[0])(*(torch.cat(t) for t in zip(*outs)))
        return self._one(z_all)

    def _one(self, z_all: torch.Tensor):
        return self.detector(z_all, embedding=self.embedding(z_all))


def mesh_pair_features(geometry: PartGeometry, vertices: np.ndarray, block: int = 1024) -> np.ndarray:
    """Whole meshes (M, V, 3) -> their pair features (M, P, 3) float32, in blocks, no gradients."""
    with torch.no_grad():
        out = [geometry.pair_features(torch.as_tensor(np.asarray(vertices[i:i + block]), dtype=torch.float64)).float()
               for i in range(0, len(vertices), block)]
    return torch.cat(out).numpy() if out else np.zeros((0, geometry.n_pairs, 3), np.float32)


def code_mesh_logits(detector, z: np.ndarray, vertices: np.ndarray, block: int = 1024) -> np.ndarray:
    """A detector over code and mesh on meshes given whole: ``detector(z, pair features of vertices)`` (M,) logits,
    ``z`` (M, D) their codes (encode(mesh)), in blocks, eval mode, no gradients."""
    feats = mesh_pair_features(detector.geometry, vertices, block)
    if len(z) == 0:
        return np.zeros(0, np.float32)
    return batched_logits(detector, torch.as_tensor(np.asarray(z, np.float32)), torch.as_tensor(feats),
                          batch=block).numpy()


def detector_inputs(det: dict) -> str:
    """``detector.inputs`` (default ``latent``), checked."""
    inputs = str(det.get("inputs", "latent"))
    if inputs not in INPUTS:
        raise ValueError(f"detector.inputs={inputs!r}; use one of {INPUTS}")
    return inputs



def choose_run_geometry(space, z: np.ndarray, collides: np.ndarray, real, cfg: dict,
                        path: str | Path) -> PartGeometry:
    """Choose the pairs on the decoded codes ``z`` (labeled ``collides``; at most ``cfg["select_codes"]`` of them,
    an even stride) and the realistic training meshes, and save them to ``path`` (``geometry.npz``).

    Args:
        space: the latent space. z, collides: labeled codes (the bootstrap). real: realistic training rows
            (``vertices`` (M, V, 3), ``collides`` (M,): :class:`~neuralcol.samples.realistic.RealisticRows`) or None.
        cfg: ``detector.geometry`` (radius, min_hops, fold_ratio, colliding_weight, per_part, clip, select_codes).
        path: where the choice is saved.
    """
    z = np.asarray(z, np.float32)
    stride = max(1, -(-len(z) // max(1, int(cfg["select_codes"]))))
    sel = np.arange(0, len(z), stride)
    with torch.no_grad():
        meshes = [space.decode(torch.as_tensor(z[sel[i:i + 512]])).double().cpu().numpy()
                  for i in range(0, len(sel), 512)]
    v = np.concatenate(meshes) if meshes else np.zeros((0, *space.rest_vertices.shape))
    y = np.asarray(collides, bool)[sel]
    if real is not None and len(real.vertices):
        v = np.concatenate([v, real.vertices])
        y = np.concatenate([y, real.collides])
    geo = choose_geometry(space, v, y, radius=float(cfg["radius"]), min_hops=int(cfg["min_hops"]),
                          fold_ratio=float(cfg["fold_ratio"]), colliding_weight=float(cfg["colliding_weight"]),
                          per_part=int(cfg["per_part"]), clip=float(cfg["clip"]),
                          summaries=bool(cfg.get("summaries", False)),
                          summary_vertices=cfg.get("summary_vertices"),
                          summary_smooth=str(cfg.get("summary_form", "plain")) == "smooth")
    slots, mask = geo.fixed_slots
    with atomic_path(Path(path)) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, pairs=geo.contact.pairs.numpy(), slots=slots, mask=mask,
                     radius=np.float64(geo.contact.radius), clip=np.float64(geo.contact.clip),
                     n_examples=np.int64(len(v)), summaries=np.bool_(geo.summary is not None),
                     min_hops=np.int64(cfg["min_hops"]), fold_ratio=np.float64(cfg["fold_ratio"]),
                     summary_vertices=np.int64(-1 if geo.summary is None or geo.summary.max_vertices is None
                                               else geo.summary.max_vertices),
                     summary_smooth=np.bool_(geo.summary is not None and geo.summary.smooth))
    return geo



def load_run_geometry(space, path: str | Path) -> PartGeometry:
    """The pairs :func:`choose_run_geometry` saved (a resumed run builds the same detector)."""
    with np.load(Path(path), allow_pickle=False) as f:
        summaries = None
        if "summaries" in f.files and bool(f["summaries"]):
            most = int(f["summary_vertices"]) if "summary_vertices" in f.files else -1  # older files: all
            smooth = bool(f["summary_smooth"]) if "summary_smooth" in f.files else False
            summaries = space_summaries(space, int(f["min_hops"]), float(f["fold_ratio"]), most if most > 0 else None,
                                        smooth)
        return PartGeometry(f["pairs"], f["slots"], f["mask"], space.faces.detach().cpu().numpy(),
                            float(f["radius"]), float(f["clip"]), summaries)



def codes_featurizer(geometry: PartGeometry, space, block: int = 4096):
    """``codes (B, D) -> pair features (B, P, 3) float32`` of their decoded meshes, in blocks, no gradients; a
    progress line or bar when there are more than two blocks (round 0 of a paper-scale run: 2e5 codes through an
    ACAP decoder, minutes)."""

    def featurize(z: np.ndarray) -> np.ndarray:
        z = torch.as_tensor(np.asarray(z, np.float32))
        out = []
        with torch.no_grad(), progress_bar(total=len(z), desc="pair features of decoded codes", unit="code",
                                           disable=len(z) <= 2 * block) as bar:
            for i in range(0, len(z), block):
                out.append(geometry_of_codes(geometry, space, z[i:i + block]).float())
                bar.update(len(out[-1]))
        return torch.cat(out).numpy() if out else np.zeros((0, geometry.n_pairs, 3), np.float32)

    return featurize

